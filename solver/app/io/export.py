"""Export of an anatomy (and a deformed state) for ParaView, with meshio.

    paths = export_anatomy(face.anatomy, "out/face.vtu", displacement=face.u)

writes two files, VTU or XDMF after the extension of `path` (XDMF needs h5py: meshio puts
its arrays in a sidecar <stem>.h5, also returned):

<stem><ext>          the tissue mesh, one cell per brick in brick order (cell i of the file is
                     mesh.bricks[i]); point data 'displacement' (n, 3) if given, 'node_id'
                     (the source file's ids) and 'set_<name>' (n,) 0/1 per node set; cell
                     data 'element_id', 'wedge' 0/1, 'set_<name>' (m,) 0/1 per element set,
                     'principal_strain' (m, 3) (Green-Lagrange at the brick centre,
                     descending) if a displacement is given, and the caller's arrays.
<stem>_muscles<ext>  the fibres, one line cell per cable; cell data 'muscle' (index into
                     MUSCLE_NAMES), 'side' (index into SIDES), 'fibre' (index into
                     anatomy.fibres); point data 'insertion' 0/1 and 'displacement' (k, 3).
                     Left out when the anatomy has no fibres.

Coordinates are the reference ones in both files: ParaView's Warp By Vector on
'displacement' shows the deformed face with its muscles. The cable points' displacements
are muscle_points minus the reference points when muscle_points is given, else they are
interpolated from the mesh displacement (insertions stay put, as in the cable term).

Wedges. ANSYS writes a wedge as a degenerate brick I J K K M N O O: triangle I J K at the
bottom (counter-clockwise seen from the top), M N O above it, edges I-M, J-N, K-O. A VTK
wedge has triangle (0, 1, 2) with its right-hand normal pointing away from triangle
(3, 4, 5), and edges 0-3, 1-4, 2-5, so it is written (I, K, J, M, O, N). A brick collapsed
on another pair of parallel edges of one face is first rotated into the I J K K M N O O
pattern; any other degenerate brick is written as a degenerate hexahedron.

meshio comes with the package's `export` extra (solver.app.extras).
"""

from itertools import permutations, product
from pathlib import Path

import numpy as np

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.core.element import NODE_XI, shape_functions
from solver.core.embedding import locate
from solver.core.errors import ParameterError
from solver.app.extras import need
from solver.core.strain import green_lagrange_strain, principal_strains

FORMATS = {".vtu": "vtu", ".xdmf": "xdmf"}
SIDES = ("left", "right", "mid")
WEDGE_FROM_BRICK = np.array([0, 2, 1, 4, 6, 5])     # I J K K M N O O -> VTK (I, K, J, M, O, N)


def export_anatomy(anatomy, path, displacement=None, point_data=None, cell_data=None,
                   muscle_points=None):
    """Write the mesh and the muscles of anatomy; returns the written paths [Path, ...].

    displacement   (n, 3) mm nodal displacements, or None
    point_data     name -> (n,) or (n, k) extra nodal arrays
    cell_data      name -> (m,) or (m, k) extra per-brick arrays (e.g. strains)
    muscle_points  list over anatomy.fibres of (k, 3) current cable point positions
    """
    path = Path(path)
    file_format = FORMATS.get(path.suffix.lower())
    if file_format is None:
        raise ParameterError(f"cannot export to {path}: use a {' or '.join(FORMATS)} file")
    mesh = anatomy.mesh
    u = None if displacement is None else _checked(displacement, (mesh.n_nodes, 3),
                                                   "displacement")
    if file_format == "xdmf":
        _require_h5py(path)
    written = _write(path, solid_mesh(mesh, u, point_data, cell_data), file_format)
    if anatomy.fibres:
        moves = _fibre_moves(anatomy, u, muscle_points)
        muscle_path = path.with_name(f"{path.stem}_muscles{path.suffix}")
        written += _write(muscle_path, muscle_mesh(anatomy.fibres, moves), file_format)
    return written


def _require_h5py(path):
    try:
        import h5py  # noqa: F401
    except ImportError:
        raise ParameterError(f"cannot export to {path}: XDMF needs h5py (pip install h5py), "
                             "or write a .vtu file") from None


def _write(path, mesh, file_format):
    """Write one meshio.Mesh; returns the files written [Path, ...]."""
    path.parent.mkdir(parents=True, exist_ok=True)
    _meshio().write(path, mesh, file_format=file_format)
    return [path] + ([path.with_suffix(".h5")] if file_format == "xdmf" else [])


def _meshio():
    return need("meshio", "export", "export to VTU or XDMF")


def _checked(array, shape, name):
    """array as float64, refused unless its leading dimensions are shape."""
    a = np.asarray(array, dtype=np.float64)
    if a.shape[:len(shape)] != shape or not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be a finite array of shape {shape}(...), got "
                             f"{a.shape}")
    return a


# ------------------------------------------------------------------------- solid mesh

def solid_mesh(mesh, u=None, point_data=None, cell_data=None):
    """meshio.Mesh of the bricks (see the module docstring); u (n, 3) or None."""
    cells, types = vtk_cells(mesh.bricks)
    pdata = {"node_id": mesh.node_ids}
    pdata.update({f"set_{k}": _member(v, mesh.n_nodes) for k, v in mesh.node_sets.items()})
    cdata = {"element_id": mesh.element_ids, "wedge": (types == "wedge").astype(np.uint8)}
    cdata.update({f"set_{k}": _member(v, mesh.n_bricks) for k, v in mesh.element_sets.items()})
    if u is not None:
        pdata["displacement"] = u
        cdata["principal_strain"] = principal_strains(green_lagrange_strain(mesh, u))
    for k, v in (point_data or {}).items():
        pdata[k] = _checked(v, (mesh.n_nodes,), f"point data {k!r}")
    for k, v in (cell_data or {}).items():
        cdata[k] = _checked(v, (mesh.n_bricks,), f"cell data {k!r}")
    blocks, runs = _blocks(cells, types)
    return _meshio().Mesh(mesh.nodes, blocks, point_data=pdata,
                       cell_data={k: [np.asarray(v)[r] for r in runs] for k, v in cdata.items()})


def _member(ids, n):
    """(n,) uint8, 1 at ids."""
    out = np.zeros(n, dtype=np.uint8)
    out[ids] = 1
    return out


def _blocks(cells, types):
    """Cell blocks of consecutive cells of one type, in order: [(type, conn)], [slice]."""
    cut = np.flatnonzero(types[1:] != types[:-1]) + 1
    bounds = np.concatenate([[0], cut, [len(types)]])
    runs = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
    return [(str(types[r.start]), np.array(cells[r])) for r in runs], runs


def _rotations():
    """(24, 8): the brick's node orders obtained by rotating it (orientation kept)."""
    out = []
    for perm, signs in product(permutations(range(3)), product((1, -1), repeat=3)):
        rot = np.zeros((3, 3))
        rot[range(3), perm] = signs
        if np.linalg.det(rot) > 0:
            moved = NODE_XI @ rot.T
            out.append([int(np.flatnonzero((NODE_XI == p).all(axis=1))[0]) for p in moved])
    return np.array(out)


ROTATIONS = _rotations()


def vtk_cells(bricks):
    """Connectivity of bricks (m, 8) in VTK order: list (m,) of (8,) or (6,) node ids, and
    the cell types (m,) 'hexahedron' or 'wedge'."""
    cells = list(bricks)
    types = np.full(len(bricks), "hexahedron", dtype=object)
    distinct = 8 - (np.diff(np.sort(bricks, axis=1), axis=1) == 0).sum(axis=1)
    cand = bricks[:, ROTATIONS]                                     # (m, 24, 8)
    ok = ((cand[..., 2] == cand[..., 3]) & (cand[..., 6] == cand[..., 7])
          & (distinct == 6)[:, None])
    for e in np.flatnonzero(ok.any(axis=1)):
        cells[e] = cand[e, np.argmax(ok[e]), WEDGE_FROM_BRICK]
        types[e] = "wedge"
    return cells, types


# ----------------------------------------------------------------------------- strain

# ---------------------------------------------------------------------------- muscles

def fibre_displacements(anatomy, u):
    """list over anatomy.fibres of (k, 3) cable point displacements interpolated from the
    nodal displacements u (n, 3); insertion points do not move."""
    pts = np.vstack([f.points for f in anatomy.fibres])
    host, xi, _, _ = locate(anatomy.mesh, pts)
    d = np.einsum("pa,paj->pj", shape_functions(xi), u[anatomy.mesh.bricks[host]])
    d[np.concatenate([f.insertion for f in anatomy.fibres])] = 0.0
    return np.split(d, np.cumsum([len(f.points) for f in anatomy.fibres])[:-1])


def _fibre_moves(anatomy, u, muscle_points):
    """Per-fibre displacements (k, 3), or None when nothing moves."""
    if muscle_points is None:
        return None if u is None else fibre_displacements(anatomy, u)
    if len(muscle_points) != len(anatomy.fibres):
        raise ParameterError(f"muscle_points has {len(muscle_points)} fibres, the anatomy "
                             f"{len(anatomy.fibres)}")
    return [_checked(p, f.points.shape, f"muscle_points[{i}]") - f.points
            for i, (p, f) in enumerate(zip(muscle_points, anatomy.fibres))]


def muscle_mesh(fibres, moves=None):
    """meshio.Mesh of fibres: one 'line' cell per cable (see the module docstring);
    moves: list of (k, 3) point displacements per fibre, or None."""
    start = np.cumsum([0] + [len(f.points) for f in fibres])
    lines = np.vstack([np.column_stack([np.arange(a, b - 1), np.arange(a + 1, b)])
                       for a, b in zip(start[:-1], start[1:])])

    def per_cable(values):
        return np.repeat(values, [f.n_cables for f in fibres])

    cdata = {"muscle": per_cable([MUSCLE_NAMES.index(f.muscle) for f in fibres]),
             "side": per_cable([SIDES.index(f.side) for f in fibres]),
             "fibre": per_cable(np.arange(len(fibres)))}
    pdata = {"insertion": np.concatenate([f.insertion for f in fibres]).astype(np.uint8)}
    if moves is not None:
        pdata["displacement"] = np.vstack(moves)
    return _meshio().Mesh(np.vstack([f.points for f in fibres]), [("line", lines)],
                       point_data=pdata, cell_data={k: [v] for k, v in cdata.items()})
