"""The generic face: a procedural finite-element model of the lower and mid face.

    anatomy = generic_face(level="paper", half=False)

The project's offline default anatomy, built from code alone (no data files), after the
ANSYS face model of Nazari, Perrier, Chabanas and Payan. Units mm; axes as in base.py.

A point is addressed by (phi, z, w): the angle phi around a U-shaped skull surface (0
mid-sagittal, sign = sign of x), the height z, and the fraction w of the tissue thickness
(0 skull, 1 skin). generic_shape makes the surfaces (the skin is the skull surface pushed
out by a thickness field; full-face bounding box 143.5 x 127.8 x 137.8 mm, as the paper's
Table 1); generic_grid the mesh: columns of constant phi, nodes finer around the mouth
slit, wedges where neighbouring columns hold different numbers of rows; generic_muscles
ten muscles per side with the fibre and cable counts of the paper's Table 3, and the
rigid teeth. The (phi, z, w) map does not depend on the level (coarse | medium | paper |
fine): a finer level samples it more densely.

The mouth slit is two rows of nodes, one per lip, SLIT_GAP (0.4 mm) apart at the mid-line
and joined at the corners: the lips separate and touch. Three layers of bricks:
'layer_inner' (w 0-0.45) and 'layer_middle' (0.45-0.82), the hypodermis where the muscles
run, and 'layer_outer' (0.82-1), epidermis and dermis; one brick row each, two at 'fine'
(``rows`` sets it at any level). Bricks are ordered I..L on the skull side, M..P on the
skin side; wedges repeat K = L and O = P.

Sets and landmarks: node_sets 'fixed', 'fixed_mandible' (they follow the jaw),
'fixed_skull', 'midsagittal', 'inner_surface', 'outer_surface', 'slit_upper',
'slit_lower'; element_sets the three layers; landmarks upper/lower_lip_edge,
upper/lower_lip_front, corner_left, corner_right; contact_surfaces 'upper_lip',
'lower_lip' ((f, 4) outward boundary faces; a wedge face repeats a node id);
rigid_surfaces 'upper_teeth', 'lower_teeth'.

Half face (half=True): solver.face.anatomy.half.half_anatomy of the full face: bricks with
every node at x <= 0, the left fibres; 'corner_right' is omitted, full-face outputs follow
by symmetry.

Construction (surfaces, grid, slit, layers, teeth) and the sets' definitions:
docs/method.md, section 'The generic face: construction'.
"""

import numpy as np

from solver.core.errors import ParameterError
from solver.core.mesh import Mesh
from solver.face.anatomy import generic_grid, generic_muscles, generic_shape
from solver.face.anatomy.base import Anatomy
from solver.face.anatomy.half import half_anatomy

# level -> (target element size away from the lips (mm), brick rows per layer)
LEVELS = {"coarse": (9.0, 1), "medium": (6.0, 1), "paper": (4.05, 1), "fine": (2.7, 2)}
MAX_ROWS = 4
LAYERS = (("layer_inner", 0.45), ("layer_middle", 0.82), ("layer_outer", 1.0))


def _thickness_levels(rows):
    """w (n+1,) of the node levels through the thickness and the layer name (n,) of
    each brick row, `rows` rows per layer."""
    w, names, lo = [0.0], [], 0.0
    for name, hi in LAYERS:
        w += list(np.linspace(lo, hi, rows + 1)[1:])
        names += [name] * rows
        lo = hi
    return np.array(w), names


def _layer_sets(names, nc):
    """Element sets name -> brick ids, for brick rows named names (n,) of nc bricks each."""
    return {name: np.concatenate([np.arange(k * nc, (k + 1) * nc)
                                  for k, n in enumerate(names) if n == name])
            for name, _ in LAYERS}


def _extrude(grid, w):
    """Nodes (ns (n+1), 3) at the thickness levels w (n+1,), node id = level * ns + s, and
    bricks (nc n, 8), brick id = row * nc + cell."""
    ns = len(grid.phi)
    nodes = np.concatenate([generic_shape.position(grid.phi, grid.z, wk) for wk in w])
    nodes[:, 2] += np.concatenate([generic_shape.slit_opening(grid.phi, grid.z, wk)
                                   for wk in w])
    cells = grid.cells[:, [1, 0, 3, 2]]    # I J K L counter-clockwise from the skin; K = L
    bricks = np.concatenate([np.hstack([cells + k * ns, cells + (k + 1) * ns])
                             for k in range(len(w) - 1)])
    return nodes, bricks


def _node_sets(grid, nodes, n_levels):
    """Named node sets of the extruded grid (see the module docstring)."""
    ns = len(grid.phi)
    inner = np.arange(ns)
    cut = generic_shape.in_mouth(grid.column_phi)
    every = ns * np.arange(n_levels)[:, None]
    free = generic_muscles.is_free(grid.phi, grid.z)
    low = grid.z < generic_shape.row_line(grid.phi)
    return {"fixed": inner[~free],
            "fixed_skull": inner[~free & ~low],
            "fixed_mandible": inner[~free & low],
            "midsagittal": np.flatnonzero(nodes[:, 0] == 0.0),
            "inner_surface": inner,
            "outer_surface": inner + ns * (n_levels - 1),
            "slit_upper": (grid.anchors["slit_upper"][cut] + every).ravel(),
            "slit_lower": (grid.anchors["slit_lower"][cut] + every).ravel()}


def _landmarks(grid, n_levels):
    """Skin-side landmark node ids (see the module docstring)."""
    skin = len(grid.phi) * (n_levels - 1)
    mid = len(grid.column_phi) // 2
    left, right = grid.corner_columns
    a = grid.anchors
    return {"upper_lip_edge": int(skin + a["slit_upper"][mid]),
            "lower_lip_edge": int(skin + a["slit_lower"][mid]),
            "upper_lip_front": int(skin + a["front_upper"][mid]),
            "lower_lip_front": int(skin + a["front_lower"][mid]),
            "corner_left": int(skin + a["slit_upper"][left]),
            "corner_right": int(skin + a["slit_upper"][right])}


def _contact_surfaces(mesh, grid):
    """'upper_lip', 'lower_lip' (f, 4): slit faces and free skull-side faces of each lip."""
    ns = len(grid.phi)
    faces = mesh.boundary_faces()
    s = faces % ns                                # surface node of each face node
    inner = np.all(faces < ns, axis=1) & np.all(generic_muscles.is_free(grid.phi[s], grid.z[s]),
                                                axis=1)
    above = grid.z[s].mean(axis=1) > generic_shape.row_line(grid.phi[s].mean(axis=1))
    cut = generic_shape.in_mouth(grid.column_phi)
    corners = grid.anchors["slit_upper"][list(grid.corner_columns)]
    out = {}
    for name, side in (("upper_lip", above), ("lower_lip", ~above)):
        slit = grid.anchors["slit_" + name.split("_")[0]][cut]
        on_slit = (np.all(np.isin(s, slit) | np.isin(s, corners), axis=1)
                   & np.any(np.isin(s, slit), axis=1))
        out[name] = faces[on_slit | (inner & side)]
    return out


def generic_face(level="coarse", half=False, rows=None):
    """The generic face at a mesh level ('coarse', 'medium', 'paper', 'fine'); half=True
    keeps x <= 0 (see the module docstring); rows: brick rows per layer through the
    thickness (1 to MAX_ROWS; default the level's). Returns an Anatomy named 'generic'."""
    if level not in LEVELS:
        raise ParameterError(f"level {level!r} is not one of {list(LEVELS)}")
    h, level_rows = LEVELS[level]
    rows = level_rows if rows is None else rows
    if isinstance(rows, bool) or not isinstance(rows, int) or not 1 <= rows <= MAX_ROWS:
        raise ParameterError(f"rows = {rows!r} must be an integer from 1 to {MAX_ROWS}")
    grid = generic_grid.surface_grid(h)
    w, layer_names = _thickness_levels(rows)
    nodes, bricks = _extrude(grid, w)
    mesh = Mesh(nodes, bricks, _node_sets(grid, nodes, len(w)),
                _layer_sets(layer_names, len(grid.cells)))
    anatomy = Anatomy("generic", mesh, generic_muscles.fibres(), _landmarks(grid, len(w)),
                      _contact_surfaces(mesh, grid), generic_muscles.teeth())
    return half_anatomy(anatomy) if half else anatomy
