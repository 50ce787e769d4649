"""Export (meshio), strain, pictures and the `facefmu anatomy` command.

The reference-face cases use ../shared/data/reference-face (relative to the project root)
or FACEFMU_REFERENCE_FACE, and skip when it is absent; the generic-face case skips while
solver.face.anatomy.generic does not exist.
"""

import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

from facefmu.cli import main
from solver.face.anatomy.base import MUSCLE_NAMES, Anatomy, Fibre
from solver.core.errors import ParameterError
from solver.app.io import export_anatomy, green_lagrange_strain, principal_strains
from solver.app.io.export import SIDES, vtk_cells
from solver.core.mesh import Mesh
from solver.core.meshgen import box
from solver.app.plot import plot_anatomy
from solver.face.anatomy.reference import reference_face_dir
from conftest import needs_reference_face

DATA = reference_face_dir()
needs_reference = needs_reference_face


def _block_anatomy():
    """A 3 x 2 x 2 block with a wedge (brick 0 collapsed K = L, O = P), two fibres."""
    mesh = box(3, 2, 2, size=(30.0, 20.0, 20.0), origin=(-15.0, 0.0, 0.0))
    bricks = mesh.bricks.copy()
    bricks[0, 3], bricks[0, 7] = bricks[0, 2], bricks[0, 6]
    mesh = Mesh(mesh.nodes, bricks, node_sets={"fixed": mesh.node_sets["ymin"],
                                                "midsagittal": [0]},
                element_sets={"layer_outer": [1, 2]})
    line = np.linspace(0.0, 1.0, 4)[:, None]
    fibres = [Fibre("OOP", "left", np.array([-12.0, 12.0, 10.0]) + line * [10.0, 0, 0],
                    np.array([True, False, False, False])),
              Fibre("ZYG", "right", np.array([5.0, 5.0, 5.0]) + line[:3] * [5.0, 5.0, 5.0],
                    np.zeros(3, bool))]
    return Anatomy("block", mesh, fibres, {"upper_lip_edge": 5})


# ------------------------------------------------------------------------- export

def test_export_round_trip(tmp_path, rng):
    anatomy = _block_anatomy()
    mesh = anatomy.mesh
    u = rng.normal(scale=0.1, size=(mesh.n_nodes, 3))
    moved = [f.points + 0.5 for f in anatomy.fibres]
    paths = export_anatomy(anatomy, tmp_path / "out" / "b.vtu", displacement=u,
                           cell_data={"strain_max": np.arange(mesh.n_bricks, dtype=float)},
                           point_data={"temp": np.ones(mesh.n_nodes)}, muscle_points=moved)
    assert paths == [tmp_path / "out" / "b.vtu", tmp_path / "out" / "b_muscles.vtu"]
    solid = meshio.read(paths[0])
    assert len(solid.points) == mesh.n_nodes
    assert [c.type for c in solid.cells] == ["wedge", "hexahedron"]
    assert sum(len(c.data) for c in solid.cells) == mesh.n_bricks
    np.testing.assert_allclose(solid.point_data["displacement"], u)
    np.testing.assert_array_equal(solid.point_data["set_fixed"][mesh.node_sets["fixed"]], 1)
    assert solid.point_data["set_fixed"].sum() == len(mesh.node_sets["fixed"])
    cell = {k: np.concatenate(v) for k, v in solid.cell_data.items()}
    np.testing.assert_array_equal(cell["wedge"], [1] + [0] * (mesh.n_bricks - 1))
    np.testing.assert_array_equal(cell["set_layer_outer"], np.isin(range(mesh.n_bricks), [1, 2]))
    np.testing.assert_array_equal(cell["strain_max"], np.arange(mesh.n_bricks))
    assert cell["principal_strain"].shape == (mesh.n_bricks, 3)
    muscles = meshio.read(paths[1])
    assert [c.type for c in muscles.cells] == ["line"]
    assert len(muscles.cells[0].data) == sum(f.n_cables for f in anatomy.fibres) == 5
    np.testing.assert_array_equal(muscles.cell_data["muscle"][0],
                                  [MUSCLE_NAMES.index("OOP")] * 3 + [MUSCLE_NAMES.index("ZYG")] * 2)
    np.testing.assert_array_equal(muscles.cell_data["side"][0],
                                  [SIDES.index("left")] * 3 + [SIDES.index("right")] * 2)
    np.testing.assert_allclose(muscles.point_data["displacement"], 0.5)


def test_export_fibres_follow_the_mesh(tmp_path):
    """Without muscle_points, cable points move with the mesh; insertions stay put."""
    anatomy = _block_anatomy()
    shift = np.tile([1.0, -2.0, 0.5], (anatomy.mesh.n_nodes, 1))
    paths = export_anatomy(anatomy, tmp_path / "b.vtu", displacement=shift)
    d = meshio.read(paths[1]).point_data["displacement"]
    insertion = np.concatenate([f.insertion for f in anatomy.fibres])
    np.testing.assert_allclose(d[~insertion], np.broadcast_to(shift[0], d[~insertion].shape),
                               atol=1e-9)
    np.testing.assert_allclose(d[insertion], 0.0)


def test_export_xdmf(tmp_path):
    anatomy = _block_anatomy()
    paths = export_anatomy(anatomy, tmp_path / "b.xdmf")
    assert [p.name for p in paths] == ["b.xdmf", "b.h5", "b_muscles.xdmf", "b_muscles.h5"]
    assert sum(len(c.data) for c in meshio.read(paths[0]).cells) == anatomy.mesh.n_bricks


def test_export_refuses_bad_input(tmp_path):
    anatomy = _block_anatomy()
    with pytest.raises(ParameterError, match="b.obj"):
        export_anatomy(anatomy, tmp_path / "b.obj")
    with pytest.raises(ParameterError, match="displacement"):
        export_anatomy(anatomy, tmp_path / "b.vtu", displacement=np.zeros((3, 3)))
    with pytest.raises(ParameterError, match="'bad'"):
        export_anatomy(anatomy, tmp_path / "b.vtu", cell_data={"bad": np.zeros(2)})


@pytest.mark.parametrize("collapse", [((2, 3), (6, 7)), ((0, 1), (4, 5)), ((1, 5), (2, 6))])
def test_wedge_node_order(collapse):
    """Any prism collapse becomes a VTK wedge: (0, 1, 2)'s normal points away from (3, 4, 5),
    edges 0-3, 1-4, 2-5 are the brick's, and the six corners are kept."""
    mesh = box(1, 1, 1, size=(2.0, 3.0, 4.0))
    brick = mesh.bricks[0].copy()
    for a, b in collapse:
        brick[b] = brick[a]
    cells, types = vtk_cells(brick[None])
    assert types[0] == "wedge"
    w, x = cells[0], mesh.nodes
    normal = np.cross(x[w[1]] - x[w[0]], x[w[2]] - x[w[0]])
    assert normal @ (x[w[3:]].mean(axis=0) - x[w[:3]].mean(axis=0)) < 0
    assert sorted(w) == sorted(set(brick))
    edges = {frozenset(brick[[a, b]]) for a, b in
             [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4),
              (0, 4), (1, 5), (2, 6), (3, 7)]}
    assert all(frozenset((w[i], w[i + 3])) in edges for i in range(3))


# ------------------------------------------------------------------------- strain

def test_green_lagrange_strain_of_homogeneous_deformation(rng):
    mapping = lambda p: p + 0.15 * np.sin(p[:, [1, 2, 0]])      # noqa: E731  (curved bricks)
    mesh = box(3, 2, 2, size=(3.0, 2.0, 2.0), mapping=mapping)
    grad = rng.normal(scale=0.2, size=(3, 3))
    u = mesh.nodes @ grad.T + rng.normal(size=3)
    f = np.eye(3) + grad
    expected = 0.5 * (f.T @ f - np.eye(3))
    strain = green_lagrange_strain(mesh, u)
    np.testing.assert_allclose(strain, np.broadcast_to(expected, strain.shape), atol=1e-12)
    np.testing.assert_allclose(principal_strains(strain)[0], np.linalg.eigvalsh(expected)[::-1])


def test_green_lagrange_strain_of_a_rotation_is_zero():
    mesh = box(2, 2, 2)
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    strain = green_lagrange_strain(mesh, mesh.nodes @ rot.T - mesh.nodes)
    np.testing.assert_allclose(strain, 0.0, atol=1e-12)


# ------------------------------------------------------------------------ picture

def test_plot_block(tmp_path):
    anatomy = _block_anatomy()
    path = plot_anatomy(anatomy, tmp_path / "pics" / "b.png",
                        displacement=np.full((anatomy.mesh.n_nodes, 3), 0.3), title="block")
    assert Path(path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- CLI

def test_cli_missing_folder(tmp_path, capsys):
    missing = tmp_path / "no-such-face"
    assert main(["anatomy", str(missing)]) == 2
    err = capsys.readouterr().err.strip()
    assert str(missing) in err and len(err.splitlines()) == 1


def test_cli_bad_level(capsys):
    with pytest.raises(SystemExit) as e:
        main(["anatomy", "generic", "--level", "huge"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "huge" in err and len(err.splitlines()) == 1


def test_cli_version(capsys):
    import solver
    assert main(["version"]) == 0
    assert capsys.readouterr().out.strip() == solver.__version__


@needs_reference
def test_cli_reference_face(tmp_path, capsys):
    vtu, png = tmp_path / "face.vtu", tmp_path / "face.png"
    assert main(["anatomy", str(DATA), "--export", str(vtu), "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "nodes 8720" in out and "bricks 6342" in out and "wedges 318" in out
    assert all(m in out for m in MUSCLE_NAMES) and "upper_lip_edge" in out
    all_row = next(line.split() for line in out.splitlines() if line.strip().startswith("all"))
    assert all_row[1:] == ["18", "18", "36", "101", "101", "202"]
    solid = meshio.read(vtu)
    assert len(solid.points) == 8720
    assert {c.type: len(c.data) for c in solid.cells} == {"hexahedron": 6024, "wedge": 318}
    assert len(meshio.read(tmp_path / "face_muscles.vtu").cells[0].data) == 202
    assert png.stat().st_size > 10_000


@needs_reference
def test_cli_broken_file(tmp_path, capsys):
    broken = tmp_path / "face"
    broken.mkdir()
    for f in DATA.iterdir():
        (broken / f.name).symlink_to(f)
    (broken / "newface.elem").unlink()
    (broken / "newface.elem").write_text("garbage\n")
    assert main(["anatomy", str(broken)]) == 2
    err = capsys.readouterr().err.strip()
    assert "newface.elem" in err and len(err.splitlines()) == 1


@needs_reference
def test_cli_as_module(tmp_path):
    res = subprocess.run([sys.executable, "-m", "facefmu.cli", "anatomy", str(DATA), "--half"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "half face" in res.stdout and "corner_right" not in res.stdout


def test_cli_generic(tmp_path, capsys):
    pytest.importorskip("solver.face.anatomy.generic")
    png = tmp_path / "generic.png"
    assert main(["anatomy", "generic", "--half", "--export", str(tmp_path / "g.vtu"),
                 "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "bricks" in out and "upper_lip_edge" in out
    assert png.stat().st_size > 10_000
    assert (tmp_path / "g.vtu").is_file() and (tmp_path / "g_muscles.vtu").is_file()
