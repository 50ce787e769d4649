"""The procedural generic face: counts per level, geometry, symmetry, muscles, sets,
landmarks, slit, teeth, half face, and the same geometry at every level."""


import numpy as np
import pytest
from scipy.spatial import cKDTree

from solver.face.anatomy import LANDMARK_NAMES, MUSCLE_NAMES
from solver.face.anatomy.generic import LEVELS, generic_face
from solver.face.anatomy.generic_shape import (PHI_CORNER, SLIT_GAP, SLIT_OPEN,
                                               SLIT_OPEN_DEPTH, SLIT_OPEN_REACH, Z_SLIT,
                                               slit_opening)
from solver.core.element import natural_coordinates
from solver.core.errors import ParameterError

PAPER_BOX = np.array([143.52, 127.77, 137.81])
PAPER_BRICKS, PAPER_NODES = 6344, 8736
TABLE3 = {"LLSAN": (2, 12), "LAO": (1, 9), "ZYG": (2, 15), "RIS": (1, 6), "BUC": (2, 12),
          "DAO": (2, 12), "DLI": (2, 11), "MENT": (2, 11), "OOP": (2, 14), "OOM": (2, 14)}
BONY = {"LLSAN": -1, "LAO": -1, "ZYG": -1, "RIS": -1, "BUC": -1, "DAO": -1, "DLI": -1,
        "MENT": 0}                     # index of the insertion point in each fibre
FAST = ("coarse", "medium", "paper")


@pytest.fixture(scope="module")
def faces():
    return {level: generic_face(level) for level in FAST}


@pytest.fixture(scope="module")
def paper(faces):
    return faces["paper"]


@pytest.fixture(scope="module")
def coarse(faces):
    return faces["coarse"]


@pytest.fixture(scope="module")
def half():
    return generic_face("paper", half=True)


def inside(mesh, points, tol=1e-6):
    """(p,) bool: each point lies in (or on) some brick, by natural coordinates after a
    bounding-box prefilter."""
    xe = mesh.nodes[mesh.bricks]
    lo, hi = xe.min(axis=1) - 1e-6, xe.max(axis=1) + 1e-6
    out = np.zeros(len(points), dtype=bool)
    for i, p in enumerate(points):
        for e in np.flatnonzero(np.all((lo <= p) & (p <= hi), axis=1)):
            if np.abs(natural_coordinates(xe[e], p)).max() <= 1.0 + tol:
                out[i] = True
                break
    return out


def lm(anatomy, name):
    return anatomy.mesh.nodes[anatomy.landmarks[name]]


# counts and geometry

def test_counts_per_level(faces):
    n = {k: (a.mesh.n_bricks, a.mesh.n_nodes) for k, a in faces.items()}
    assert n["coarse"][0] <= 1500
    assert n["coarse"][0] < n["medium"][0] < n["paper"][0]
    assert abs(n["paper"][0] / PAPER_BRICKS - 1.0) <= 0.10
    assert abs(n["paper"][1] / PAPER_NODES - 1.0) <= 0.10
    assert 0.02 <= faces["paper"].mesh.is_wedge.mean() <= 0.08


def test_wedges_are_ansys_degenerate_bricks(paper):
    b = paper.mesh.bricks[paper.mesh.is_wedge]
    assert len(b)
    assert np.all(b[:, 2] == b[:, 3]) and np.all(b[:, 6] == b[:, 7])
    assert np.all(np.array([len(set(r)) for r in b]) == 6)


@pytest.mark.parametrize("level", FAST)
def test_bounding_box_as_the_paper(faces, level):
    box = faces[level].mesh.bounding_box
    assert np.all(np.abs(box / PAPER_BOX - 1.0) <= 0.05), box


def test_same_geometry_across_levels(faces):
    ref = faces["paper"]
    for a in faces.values():
        assert np.allclose(a.mesh.bounding_box, ref.mesh.bounding_box, rtol=0.01)
        for name in LANDMARK_NAMES:
            assert np.allclose(lm(a, name), lm(ref, name), atol=1e-6), name
        for f, g in zip(a.fibres, ref.fibres):
            assert np.allclose(f.points, g.points, atol=1e-9)
        for k, s in a.rigid_surfaces.items():
            assert np.array_equal(s.vertices, ref.rigid_surfaces[k].vertices)


@pytest.mark.parametrize("level", FAST)
def test_positive_det_j_and_quality(faces, level):
    mesh = faces[level].mesh                      # Mesh rejects det J <= 0 on construction
    scaled = mesh.det_j.min(axis=1) / mesh.det_j.max(axis=1)
    assert scaled.min() > 0.15
    assert scaled[~mesh.is_wedge].min() > 0.5


@pytest.mark.slow
def test_fine_level(paper):
    fine = generic_face("fine")
    assert fine.mesh.n_bricks >= 4 * paper.mesh.n_bricks
    assert fine.mesh.det_j.min() > 0.0
    assert np.allclose(fine.mesh.bounding_box, paper.mesh.bounding_box, rtol=0.01)
    for name in LANDMARK_NAMES:
        assert np.allclose(lm(fine, name), lm(paper, name), atol=1e-6)
    assert np.all(inside(fine.mesh, np.vstack([f.points for f in fine.fibres])))


def test_unknown_level():
    assert set(LEVELS) == {"coarse", "medium", "paper", "fine"}
    with pytest.raises(ParameterError):
        generic_face("huge")


def test_mirror_symmetry(paper):
    x = paper.mesh.nodes
    m = x * [-1.0, 1.0, 1.0]
    a, b = x[np.lexsort(x.T)], m[np.lexsort(m.T)]
    assert np.array_equal(a, b)
    assert np.any(x[:, 0] < -50) and np.any(x[:, 0] > 50)


def test_layers_partition_the_bricks(paper):
    sets = paper.mesh.element_sets
    ids = np.concatenate([sets[k] for k in ("layer_inner", "layer_middle", "layer_outer")])
    assert np.array_equal(np.sort(ids), np.arange(paper.mesh.n_bricks))
    assert len(sets["layer_inner"]) == len(sets["layer_outer"])
    # the outer layer (skin) is the thinnest: compare volumes
    vol = paper.mesh.volumes
    assert vol[sets["layer_outer"]].sum() < vol[sets["layer_inner"]].sum()


def test_thickness_of_lips_and_cheeks(paper):
    x = paper.mesh.nodes
    ns = len(paper.mesh.node_sets["inner_surface"])     # node id = level * ns + column node
    depth = np.linalg.norm(x[ns * 3:] - x[:ns], axis=1)     # skin minus skull, per column
    assert 12.0 <= depth[paper.landmarks["upper_lip_front"] - 3 * ns] <= 15.5
    assert 12.0 <= depth[paper.landmarks["lower_lip_front"] - 3 * ns] <= 15.5
    assert 10.0 <= depth.max() <= 16.0 and depth.min() >= 4.0


# node sets, landmarks, slit

def test_node_sets(paper):
    x, sets = paper.mesh.nodes, paper.mesh.node_sets
    assert np.array_equal(sets["midsagittal"], np.flatnonzero(x[:, 0] == 0.0))
    assert len(sets["midsagittal"]) > 0
    assert len(sets["inner_surface"]) == len(sets["outer_surface"])
    assert not np.intersect1d(sets["inner_surface"], sets["outer_surface"]).size
    assert np.all(np.isin(sets["fixed"], sets["inner_surface"]))


def test_fixed_set_leaves_lips_and_cheeks_free(paper):
    x, fixed = paper.mesh.nodes, paper.mesh.node_sets["fixed"]
    assert 0.3 * len(paper.mesh.node_sets["inner_surface"]) < len(fixed)
    corner = abs(lm(paper, "corner_left")[0])
    slit = lm(paper, "upper_lip_edge")[2]
    lips = np.flatnonzero((np.abs(x[:, 0]) < corner) & (np.abs(x[:, 2] - slit) < 12.0))
    assert len(lips) and not np.intersect1d(fixed, lips).size
    assert not np.isin(list(paper.landmarks.values()), fixed).any()


def test_landmarks(paper):
    assert set(paper.landmarks) == set(LANDMARK_NAMES)
    assert np.all(np.isin(list(paper.landmarks.values()), paper.mesh.node_sets["outer_surface"]))
    ue, le = lm(paper, "upper_lip_edge"), lm(paper, "lower_lip_edge")
    uf, lf = lm(paper, "upper_lip_front"), lm(paper, "lower_lip_front")
    assert ue[0] == le[0] == uf[0] == lf[0] == 0.0
    assert 0.0 <= ue[2] - le[2] <= 1.0
    assert uf[1] > ue[1] + 2.0 and lf[1] > le[1] + 2.0
    assert uf[2] > ue[2] and lf[2] < le[2]
    cl, cr = lm(paper, "corner_left"), lm(paper, "corner_right")
    assert cl[0] < -15.0 and np.array_equal(cl * [-1, 1, 1], cr)
    assert abs(cl[2] - ue[2]) < 1.0 and cl[1] < ue[1]


@pytest.mark.parametrize("which", ["upper", "lower"])
def test_front_is_the_most_anterior_point_of_the_lip(paper, which):
    x = paper.mesh.nodes
    skin = paper.mesh.node_sets["outer_surface"]
    mid = skin[x[skin, 0] == 0.0]
    edge = lm(paper, f"{which}_lip_edge")[2]
    sign = 1.0 if which == "upper" else -1.0
    lip = mid[(sign * (x[mid, 2] - edge) >= 0.0) & (sign * (x[mid, 2] - edge) < 12.0)]
    assert x[lip, 1].max() - lm(paper, f"{which}_lip_front")[1] < 0.3


def test_slit_cuts_the_lips_apart(paper):
    sets, bricks = paper.mesh.node_sets, paper.mesh.bricks
    up, lo = sets["slit_upper"], sets["slit_lower"]
    assert paper.landmarks["upper_lip_edge"] != paper.landmarks["lower_lip_edge"]
    assert paper.landmarks["upper_lip_edge"] in up and paper.landmarks["lower_lip_edge"] in lo
    assert len(up) == len(lo) > 0 and not np.intersect1d(up, lo).size
    touches_up = np.isin(bricks, up).any(axis=1)
    touches_lo = np.isin(bricks, lo).any(axis=1)
    assert touches_up.any() and not (touches_up & touches_lo).any()
    x = paper.mesh.nodes
    gap = x[up, 2] - x[lo, 2]                       # paired by construction order
    assert np.all((gap >= 0.0) & (gap <= SLIT_GAP + 2 * SLIT_OPEN + 1e-9))
    skin = np.isin(up, paper.mesh.node_sets["outer_surface"])
    assert np.all(gap[skin] <= 1.0)                 # closed lips touch on their outer part
    assert np.allclose(x[up, :2], x[lo, :2], atol=1.0)
    inner = up[np.isin(up, paper.mesh.node_sets["inner_surface"])]
    mid = inner[x[inner, 0] == 0.0]
    assert len(mid) == 1
    assert gap[np.flatnonzero(up == mid[0])[0]] == pytest.approx(SLIT_GAP + 2 * SLIT_OPEN)


def test_slit_opening_only_opens_the_slit_at_the_skull_side():
    phi = np.radians(np.linspace(-30.0, 30.0, 61))[:, None]
    z = Z_SLIT + np.linspace(-12.0, 12.0, 97)[None, :]
    for w in (0.0, 0.2):
        dz = slit_opening(phi, z, w)
        assert np.all(dz * np.sign(z - Z_SLIT) >= 0.0)          # away from the slit
        assert np.abs(dz).max() <= SLIT_OPEN * (1.0 - w / SLIT_OPEN_DEPTH) + 1e-12
        assert np.all(dz[np.abs(phi[:, 0]) >= PHI_CORNER] == 0.0)
        assert np.all(np.diff(z + dz, axis=1) > 0.0)           # columns stay ordered
    assert np.all(slit_opening(phi, z, SLIT_OPEN_DEPTH) == 0.0)
    assert np.all(slit_opening(phi, z, 1.0) == 0.0)
    assert slit_opening(0.0, Z_SLIT + 0.5 * SLIT_GAP, 0.0) == pytest.approx(SLIT_OPEN)
    far = Z_SLIT + 0.5 * SLIT_GAP + SLIT_OPEN_REACH
    assert slit_opening(0.0, far, 0.0) == 0.0 and slit_opening(0.0, -far + 2 * Z_SLIT, 0.0) == 0.0


def test_contact_surfaces(paper):
    faces = {tuple(sorted(f)) for f in paper.mesh.boundary_faces()}
    up, lo = paper.contact_surfaces["upper_lip"], paper.contact_surfaces["lower_lip"]
    for f in (up, lo):
        assert f.ndim == 2 and f.shape[1] == 4 and len(f) > 0
        assert all(tuple(sorted(r)) in faces for r in f)
    assert np.all(np.isin(paper.mesh.node_sets["slit_upper"], up))
    assert np.all(np.isin(paper.mesh.node_sets["slit_lower"], lo))
    assert not np.isin(paper.mesh.node_sets["slit_upper"], lo).any()
    x = paper.mesh.nodes
    assert x[up].mean(axis=(0, 1))[2] > x[lo].mean(axis=(0, 1))[2]


# muscles

def test_table3_counts_per_side(paper):
    assert set(f.muscle for f in paper.fibres) == set(MUSCLE_NAMES)
    for side in ("left", "right"):
        for m in MUSCLE_NAMES:
            fs = [f for f in paper.fibres if f.muscle == m and f.side == side]
            assert (len(fs), sum(f.n_cables for f in fs)) == TABLE3[m], (m, side)


def test_fibres_mirror_and_sides(paper):
    left = [f for f in paper.fibres if f.side == "left"]
    right = [f for f in paper.fibres if f.side == "right"]
    assert len(left) == len(right)
    for f, g in zip(left, right):
        assert f.muscle == g.muscle
        assert np.all(f.points[:, 0] <= 0.0) and np.all(g.points[:, 0] >= 0.0)
        assert np.array_equal(f.points * [-1, 1, 1], g.points)
        assert np.array_equal(f.insertion, g.insertion)


@pytest.mark.parametrize("level", ["coarse", "paper"])
def test_every_cable_point_inside_the_mesh(faces, level):
    a = faces[level]
    pts = np.vstack([f.points for f in a.fibres])
    ok = inside(a.mesh, pts)
    assert ok.all(), pts[~ok]


def test_insertions_on_the_skull(paper):
    x, sets = paper.mesh.nodes, paper.mesh.node_sets
    inner = sets["inner_surface"]
    for f in paper.fibres:
        if f.muscle not in BONY:
            assert not f.insertion.any(), f.muscle
            continue
        assert np.flatnonzero(f.insertion).tolist() == [BONY[f.muscle] % len(f.points)]
        p = f.points[f.insertion][0]
        d = np.linalg.norm(x[inner] - p, axis=1)
        assert d.min() < 4.0 and inner[np.argmin(d)] in sets["fixed"], f.muscle
        other = f.points[-1 - BONY[f.muscle]]          # the mobile end, in the soft tissue
        assert np.linalg.norm(x[inner] - other, axis=1).min() > 1.0, f.muscle


def test_muscle_courses(paper):
    ue = lm(paper, "upper_lip_edge")
    corner = lm(paper, "corner_right")
    for f in paper.fibres:
        if f.side != "right":
            continue
        p = f.points
        if f.muscle in ("OOP", "OOM"):
            assert p[0, 0] == 0.0 and np.linalg.norm(p[-1] - corner) < 8.0
        if f.muscle == "OOM":
            assert 1.0 < abs(p[0, 2] - ue[2]) < 5.0
        if f.muscle == "OOP":
            assert abs(p[0, 2] - ue[2]) > 8.0
        if f.muscle in ("LLSAN", "LAO", "ZYG"):
            assert p[-1, 2] > p[0, 2] + 10.0          # up to the maxilla / zygoma
        if f.muscle in ("DAO", "DLI", "MENT"):
            assert p[-1, 2] < p[0, 2] - 10.0 if f.muscle != "MENT" else p[0, 2] > p[-1, 2]
        if f.muscle in ("RIS", "BUC", "ZYG"):
            assert p[-1, 1] < p[0, 1] - 10.0           # backwards
        if f.muscle in ("RIS", "BUC"):
            assert abs(p[-1, 2] - p[0, 2]) < 12.0      # about horizontal


# teeth

def test_teeth_do_not_penetrate_the_tissue(coarse):
    for name in ("upper_teeth", "lower_teeth"):
        s = coarse.rigid_surfaces[name]
        assert s.triangles.shape[1] == 3 and s.triangles.max() < len(s.vertices)
        assert not inside(coarse.mesh, s.vertices, tol=0.0).any(), name


def test_teeth_lie_just_behind_the_lips(paper):
    x = paper.mesh.nodes
    inner = x[paper.mesh.node_sets["inner_surface"]]
    up, lo = paper.rigid_surfaces["upper_teeth"], paper.rigid_surfaces["lower_teeth"]
    tree = cKDTree(inner)
    for s in (up, lo):
        assert tree.query(s.vertices)[0].max() < 4.0
    ue = lm(paper, "upper_lip_edge")
    assert up.vertices[:, 2].mean() > ue[2] > lo.vertices[:, 2].mean()
    assert np.abs(up.vertices[:, 0]).max() > 40.0               # back along the cheeks
    front = up.vertices[np.argmax(up.vertices[:, 1])]
    assert front[1] < ue[1] - 5.0


def test_teeth_arches_meet_along_a_seam_and_do_not_overlap(coarse):
    """One surface cut in two: no triangle of one arch lies on the other (coincident
    sheets push a node twice, then once as it slides past one sheet's free edge), and
    the arches share the seam's vertices (no gap between them)."""
    up, lo = coarse.rigid_surfaces["upper_teeth"], coarse.rigid_surfaces["lower_teeth"]
    c_up = up.vertices[up.triangles].mean(axis=1)
    c_lo = lo.vertices[lo.triangles].mean(axis=1)
    assert cKDTree(c_lo).query(c_up)[0].min() > 0.5
    d, _ = cKDTree(lo.vertices).query(up.vertices)
    shared = d < 1e-9
    assert shared.sum() >= 50
    assert np.ptp(up.vertices[shared][:, 0]) > 40.0        # along the whole arch


# half face

def test_half_face(paper, half):
    assert half.half and half.name == "generic"
    x = half.mesh.nodes
    assert np.all(x[:, 0] <= 0.0)
    mid = half.mesh.node_sets["midsagittal"]
    assert len(mid) and np.all(x[mid, 0] == 0.0)
    assert len(mid) == len(paper.mesh.node_sets["midsagittal"])
    assert "corner_right" not in half.landmarks
    for name in set(LANDMARK_NAMES) - {"corner_right"}:
        assert np.array_equal(lm(half, name), lm(paper, name)), name
    assert all(f.side == "left" for f in half.fibres)
    assert len(half.fibres) == len(paper.fibres) // 2
    assert 2 * half.mesh.n_bricks == paper.mesh.n_bricks
    assert np.all(inside(half.mesh, np.vstack([f.points for f in half.fibres])))
    for k in ("upper_lip", "lower_lip"):
        assert len(half.contact_surfaces[k])
    assert len(half.rigid_surfaces["upper_teeth"].triangles)


def test_rows_refine_through_the_thickness_only():
    from solver.face.anatomy.load import load_anatomy
    from solver.core.errors import ParameterError
    from solver.app.scene import SceneError, parse_scene
    one, two = (load_anatomy("generic", "coarse", True, rows=r) for r in (1, 2))
    assert two.mesh.n_bricks == 2 * one.mesh.n_bricks
    assert two.mesh.volumes.sum() == pytest.approx(one.mesh.volumes.sum(), rel=1e-12)
    for set_name in ("layer_inner", "layer_middle", "layer_outer"):
        assert len(two.mesh.element_sets[set_name]) == 2 * len(one.mesh.element_sets[set_name])
    assert parse_scene({"anatomy": {"rows": 3}}).rows == 3
    for bad in (0, 5, 1.5, True):
        with pytest.raises((ParameterError, SceneError), match="rows"):
            parse_scene({"anatomy": {"rows": bad}})
        with pytest.raises(ParameterError, match="rows"):
            load_anatomy("generic", "coarse", True, rows=bad)
