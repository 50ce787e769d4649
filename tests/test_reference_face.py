"""The published ANSYS reference face: reading, counts, geometry, muscles, landmarks, errors.

The data lives outside the repository, in ../shared/data/reference-face (relative to the
project root) or wherever FACEFMU_REFERENCE_FACE points; the tests skip when it is absent.
Tests that corrupt files work on copies in tmp_path.
"""

import shutil

import numpy as np
import pytest

from solver.face.anatomy import LANDMARK_NAMES, MUSCLE_NAMES
from solver.face.anatomy.ansys import _orient, load_ansys_face
from solver.core.element import reference_geometry
from solver.core.errors import FaceFMUError, MeshFileError
from solver.face.anatomy.reference import reference_face_dir

DATA = reference_face_dir()
if not (DATA / "newface.node").is_file():
    pytest.skip(f"reference face data not found in {DATA} (set FACEFMU_REFERENCE_FACE to "
                "its folder)", allow_module_level=True)

# (fibres, cables) on one side. The README's table counts muscles.elem; the fibres follow
# the macro, which closes each OOP fibre at the mid-plane: 14 cables a side (as the
# paper's Table 3), not muscles.elem's 12. OOM: 13 as the README.
PER_SIDE = {"LLSAN": (2, 14), "LAO": (2, 10), "ZYG": (1, 7), "RIS": (1, 5), "BUC": (2, 10),
            "DAO": (2, 10), "DLI": (2, 9), "MENT": (2, 9), "OOP": (2, 14), "OOM": (2, 13)}
INSERTIONS_PER_SIDE = {"LLSAN": 6, "BUC": 6, "MENT": 2}
MIRROR = np.array([-1.0, 1.0, 1.0])


@pytest.fixture(scope="module")
def face():
    return load_ansys_face(str(DATA))


@pytest.fixture
def copy(tmp_path):
    """A writable copy of the data folder."""
    dst = tmp_path / "face"
    dst.mkdir()
    for f in DATA.iterdir():
        shutil.copyfile(f, dst / f.name)
    return dst


def edit_line(path, number, edit):
    """Replace line number (1-based) of a file by edit(line); edit returning None drops it."""
    lines = path.read_text().splitlines(keepends=True)
    new = edit(lines[number - 1])
    lines[number - 1:number] = [] if new is None else [new]
    path.write_text("".join(lines))


# ------------------------------------------------------------------------- mesh

def test_counts(face):
    mesh = face.mesh
    assert face.name == "reference" and not face.half
    assert (mesh.n_nodes, mesh.n_bricks, int(mesh.is_wedge.sum())) == (8720, 6342, 318)
    assert mesh.node_ids[0] == 1 and mesh.element_ids[-1] == 6342


def test_bounding_box(face):
    np.testing.assert_allclose(face.mesh.bounding_box, [142.52, 127.77, 137.80], atol=0.05)


def test_jacobians_positive_at_all_gauss_points(face):
    assert face.mesh.det_j.shape == (6342, 8)
    assert face.mesh.det_j.min() > 0


def test_mirrored_mesh_is_reordered(face):
    nodes = face.mesh.nodes * MIRROR
    assert reference_geometry(nodes, face.mesh.bricks)[0].max() < 0
    det = reference_geometry(nodes, _orient(nodes, face.mesh.bricks))[0]
    assert det.min() > 0


def test_sets(face):
    mesh = face.mesh
    ns, es = mesh.node_sets, mesh.element_sets
    assert (len(ns["fixed_skull"]), len(ns["fixed_mandible"])) == (730, 322)
    np.testing.assert_array_equal(ns["fixed"], np.union1d(ns["fixed_skull"], ns["fixed_mandible"]))
    assert len(ns["midsagittal"]) == 248
    assert np.abs(mesh.nodes[ns["midsagittal"], 0]).max() < 0.02
    assert len(es["mat_1"]) == 6342
    assert (len(es["OOP_active"]), len(es["OOM_active"])) == (204, 248)


# ----------------------------------------------------------------------- muscles

def test_all_muscles_on_both_sides(face):
    for muscle in MUSCLE_NAMES:
        for side in ("left", "right"):
            fibres = [f for f in face.muscle_fibres(muscle) if f.side == side]
            counts = (len(fibres), sum(f.n_cables for f in fibres))
            assert counts == PER_SIDE[muscle], (muscle, side, counts)
    assert face.summary() == {m: (2 * f, 2 * c) for m, (f, c) in PER_SIDE.items()}


def test_right_fibres_mirror_the_left(face):
    for muscle in MUSCLE_NAMES:
        fibres = face.muscle_fibres(muscle)
        left = [f for f in fibres if f.side == "left"]
        right = [f for f in fibres if f.side == "right"]
        for fl, fr in zip(left, right):
            assert fl.points[:, 0].max() <= 1e-9 and fr.points[:, 0].min() >= -1e-9
            np.testing.assert_allclose(fr.points, fl.points * MIRROR, atol=0.01)
            np.testing.assert_array_equal(fr.insertion, fl.insertion)


def test_orbicularis_oris_closes_at_the_mid_plane(face):
    for muscle in ("OOP", "OOM"):
        upper, lower = [f for f in face.muscle_fibres(muscle) if f.side == "left"]
        assert upper.points[:, 2].mean() > lower.points[:, 2].mean()
        np.testing.assert_allclose(upper.points[-1], lower.points[0])   # mouth corner
        assert abs(upper.points[0, 0]) < 0.01 and abs(lower.points[-1, 0]) < 0.01


def test_insertions(face):
    for muscle in MUSCLE_NAMES:
        for side in ("left", "right"):
            fibres = [f for f in face.muscle_fibres(muscle) if f.side == side]
            found = sum(int(f.insertion.sum()) for f in fibres)
            assert found == INSERTIONS_PER_SIDE.get(muscle, 0), (muscle, side, found)
            for f in fibres:        # insertions are runs from fibre ends
                ins = f.insertion
                head, tail = np.argmin(np.r_[ins, False]), np.argmin(np.r_[ins[::-1], False])
                assert min(head + tail, len(ins)) == ins.sum() < len(ins)


# ---------------------------------------------------------------------- surfaces

def test_lip_contact_surfaces(face):
    nodes = face.mesh.nodes
    local = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    brick_faces = {tuple(sorted(f)) for f in face.mesh.bricks[:, local].reshape(-1, 4).tolist()}
    for name, n_faces in (("upper_lip", 640), ("lower_lip", 518)):
        faces = face.contact_surfaces[name]
        # the file's 1280 and 1036 triangles, paired into the brick faces they split
        assert faces.shape == (n_faces, 4)
        assert all(tuple(sorted(f)) in brick_faces for f in faces.tolist())
        edges = np.sort(faces[:, [0, 1, 1, 2, 2, 3, 3, 0]].reshape(-1, 2), axis=1)
        assert (np.unique(edges, axis=0, return_counts=True)[1] == 2).all()   # closed
        directed = {tuple(e) for e in faces[:, [0, 1, 1, 2, 2, 3, 3, 0]].reshape(-1, 2).tolist()}
        assert all((b, a) in directed for a, b in directed)        # consistently wound
        assert np.linalg.norm(nodes[edges[:, 0]] - nodes[edges[:, 1]], axis=1).mean() < 4.0


def test_rigid_surfaces(face):
    upper, lower = face.rigid_surfaces["upper_teeth"], face.rigid_surfaces["lower_teeth"]
    assert (upper.vertices.shape, upper.triangles.shape) == ((144, 3), (240, 3))
    assert (lower.vertices.shape, lower.triangles.shape) == ((95, 3), (144, 3))
    assert upper.vertices[:, 2].mean() > lower.vertices[:, 2].mean()


def test_landmarks(face):
    assert set(face.landmarks) == set(LANDMARK_NAMES)
    p = {k: face.mesh.nodes[v] for k, v in face.landmarks.items()}
    for k, x in p.items():
        print(f"{k:16s} node {face.mesh.node_ids[face.landmarks[k]]:5d} {np.round(x, 2)}")
    mid = ("upper_lip_edge", "lower_lip_edge", "upper_lip_front", "lower_lip_front")
    assert all(abs(p[k][0]) < 0.02 for k in mid)
    assert p["upper_lip_edge"][2] > p["lower_lip_edge"][2]
    assert p["upper_lip_front"][2] > p["upper_lip_edge"][2] > p["lower_lip_edge"][2] \
        > p["lower_lip_front"][2]
    assert p["upper_lip_front"][1] > p["upper_lip_edge"][1]
    assert p["lower_lip_front"][1] > p["lower_lip_edge"][1]
    assert p["corner_left"][0] < -15 and p["corner_right"][0] > 15
    np.testing.assert_allclose(p["corner_right"], p["corner_left"] * MIRROR, atol=0.1)
    lo, hi = face.mesh.nodes.min(axis=0), face.mesh.nodes.max(axis=0)
    for x in p.values():    # lips: front half, middle height, below the nose tip
        assert x[1] > (lo[1] + hi[1]) / 2 and lo[2] + 20 < x[2] < hi[2] - 60


# ------------------------------------------------------------------------ errors

def test_missing_folder(tmp_path):
    with pytest.raises(FaceFMUError, match="no-such-face"):
        load_ansys_face(tmp_path / "no-such-face")


def test_missing_required_file(copy):
    (copy / "muscles.node").unlink()
    with pytest.raises(FaceFMUError, match="muscles.node"):
        load_ansys_face(copy)


def test_unreadable_number_names_file_and_line(copy):
    edit_line(copy / "newface.node", 100, lambda s: s[:30] + "x" + s[31:])
    with pytest.raises(MeshFileError, match=r"newface\.node:100: cannot read y") as e:
        load_ansys_face(copy)
    assert e.value.line == 100 and e.value.path.endswith("newface.node")


def test_wrong_field_count_names_file_and_line(copy):
    edit_line(copy / "newface.elem", 7, lambda s: s[:72] + "\n")
    with pytest.raises(MeshFileError, match=r"newface\.elem:7: expected 14 .*found 12"):
        load_ansys_face(copy)


def test_element_with_missing_node_names_file_and_line(copy):
    edit_line(copy / "newface.node", 60, lambda s: None)     # node 60, in element 1
    with pytest.raises(MeshFileError, match=r"newface\.elem:1: element 1 refers to node 60"):
        load_ansys_face(copy)


def test_a_generic_scene_at_a_preset_runs_on_the_reference_face(face):
    """A scene whose preset sets the generic mesh's rows (balanced: 1) can be moved to the
    ANSYS face by an override: its own mesh, the preset's tolerances (benchmarks/fast_path.py
    case a); rows given with it are still refused."""
    from solver.core.errors import ParameterError
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    spec = {"scene": {"name": "t", "analysis": "static", "fidelity": "balanced"},
            "muscles": {"driven": ["OOP"]}}
    sim = Simulation(parse_scene(spec), anatomy=str(DATA), half=True)
    from solver.app.fidelity import PRESETS
    assert sim.scene.rows is None
    assert sim.scene.substep_tol == PRESETS["balanced"]["substep_tol"]
    assert 0 < sim.anatomy.mesh.n_nodes < face.mesh.n_nodes          # the half face
    with pytest.raises(ParameterError, match="rows"):
        Simulation(parse_scene(spec), anatomy=str(DATA), rows=2)
