"""Surface grid of the generic face in the (phi, z) parameter plane (generic.py extrudes it).

Columns of constant phi run from the jaw line to the upper edge. Each column is split at
five anchors (bottom, lower vermilion front, slit or row line, upper vermilion front,
top) into four segments whose nodes follow a spacing field: finer around the lips.
Neighbouring columns may hold different numbers of nodes in a segment; the strip between
them is zipped with quads and, where a row ends, triangles (the wedges). In the mouth
(|phi| < PHI_CORNER) the slit node of a column is two nodes, one per lip, and the strips
above and below the slit do not share them: the mesh is cut along the slit.
"""

from dataclasses import dataclass

import numpy as np

from solver.face.anatomy import generic_shape as shape

_SAMPLES = 241             # samples per segment for arc lengths and spacings


@dataclass
class SurfaceGrid:
    """Nodes and cells of the skin-side grid, before extrusion.

    phi, z        (ns,) parameters of the surface nodes
    cells         (nc, 4) node ids counter-clockwise in (phi, z); a triangle repeats its
                  last id (a, b, c, c)
    anchors       name -> (ncol,) node id per column: 'bottom', 'front_lower',
                  'slit_lower', 'slit_upper', 'front_upper', 'top' (slit_lower and
                  slit_upper coincide outside the mouth)
    column_phi    (ncol,) phi of the columns, increasing; corner_columns: (2,) the
                  column indices of the mouth corners (left, right)
    """

    phi: np.ndarray
    z: np.ndarray
    cells: np.ndarray
    anchors: dict
    column_phi: np.ndarray
    corner_columns: tuple


def _lips(phi):
    """Weight (k,) of the lip refinement: 1 in the mouth, 0 lateral to the corners."""
    return shape.smoothstep(1.6 - np.abs(phi) / shape.PHI_CORNER)


def _row_spacing(phi, z, h):
    """Target element height (mm) at (phi, z): h, finer around the mouth slit."""
    return h * (1.0 - 0.75 * _lips(phi) * np.exp(-((z - shape.Z_SLIT) / 15.0) ** 2))


def _column_spacing(phi, h):
    """Target element width (mm) at phi along the row line: h, finer in the mouth."""
    return h * (1.0 - 0.3 * _lips(phi))


def _distribute(points, sizes):
    """Nodes along a sampled curve at a target spacing, both ends included.

    points (s, 3) samples of the curve, sizes (s,) target spacing there. Returns t (n+1,),
    the nodes' fractional sample indices in [0, s-1], n = round(integral of ds / size) >= 1,
    equally spaced in that integral.
    """
    ds = np.linalg.norm(np.diff(points, axis=0), axis=1)
    density = 0.5 * (1.0 / sizes[1:] + 1.0 / sizes[:-1]) * ds
    c = np.concatenate([[0.0], np.cumsum(density)])
    n = max(1, int(round(c[-1])))
    return np.interp(np.linspace(0.0, c[-1], n + 1), c, np.arange(len(c)))


def column_angles(h):
    """Column angles phi (2I+1,), symmetric, with columns at 0 and +-PHI_CORNER."""
    right = []
    for lo, hi in ((0.0, shape.PHI_CORNER), (shape.PHI_CORNER, shape.PHI_MAX)):
        p = np.linspace(lo, hi, _SAMPLES)
        pts = shape.position(p, shape.row_line(p), 0.5)
        t = _distribute(pts, _column_spacing(p, h))
        right.append(np.interp(t, np.arange(_SAMPLES), p)[:-1])
    right = np.concatenate(right + [[shape.PHI_MAX]])
    return np.concatenate([-right[:0:-1], right])


def _column_anchors(phi):
    """Anchor heights (6,) of the column at phi: bottom, lower front, slit lower,
    slit upper, upper front, top."""
    r, g = shape.row_line(phi), 0.5 * shape.slit_gap(phi)
    up, lo = shape.lip_fronts()
    return np.array([shape.bottom_line(phi), r - lo, r - g, r + g, r + up,
                     shape.top_line(phi)])


def _column_segments(phi, h):
    """Heights of the nodes of one column: four arrays (n_k + 1,), anchors included."""
    a = _column_anchors(phi)
    segs = []
    for lo, hi in ((a[0], a[1]), (a[1], a[2]), (a[3], a[4]), (a[4], a[5])):
        z = np.linspace(lo, hi, _SAMPLES)
        t = _distribute(shape.position(phi, z, 0.5), _row_spacing(phi, z, h))
        segs.append(np.interp(t, np.arange(_SAMPLES), z))
    return segs


def zip_strip(left, right):
    """Cells (k, 4) filling the strip between two columns of node ids.

    left (p+1,), right (q+1,): ids from bottom to top; the finer side's node k is paired
    with the coarser side's node round(k * coarse / fine). Quads where both advance,
    triangles (a, b, c, c) where only the finer side does. Counter-clockwise with the
    left column at smaller phi.
    """
    p, q = len(left) - 1, len(right) - 1
    fine_is_left = p >= q
    n_f, n_c = (p, q) if fine_is_left else (q, p)
    pair = np.rint(np.arange(n_f + 1) * n_c / n_f).astype(int)
    cells = []
    for k in range(n_f):
        c0, c1 = pair[k], pair[k + 1]
        if fine_is_left:
            if c1 > c0:
                cells.append((left[k], right[c0], right[c1], left[k + 1]))
            else:
                cells.append((left[k], right[c0], left[k + 1], left[k + 1]))
        elif c1 > c0:
            cells.append((left[c0], right[k], right[k + 1], left[c1]))
        else:
            cells.append((left[c0], right[k], right[k + 1], right[k + 1]))
    return cells


def _column_nodes(phi, h, first):
    """Heights (k,) of the nodes of the column at phi, numbered from `first`, and its four
    segments as node-id arrays, bottom to top. In the mouth the slit node is doubled:
    segment 1 ends on the lower lip's node, segment 2 starts on the upper lip's."""
    segs = _column_segments(phi, h)
    cut = shape.in_mouth(phi)
    z = np.concatenate([segs[0], segs[1][1:], segs[2] if cut else segs[2][1:], segs[3][1:]])
    ids = first + np.arange(len(z))
    n0, n1, n2 = (len(s) - 1 for s in segs[:3])
    lo = n0 + n1
    up = lo + 1 if cut else lo
    return z, [ids[:n0 + 1], ids[n0:lo + 1], ids[up:up + n2 + 1], ids[up + n2:]]


def surface_grid(h):
    """The SurfaceGrid for a target element size h (mm) away from the lips."""
    cols = column_angles(h)
    zs, columns, count = [], [], 0
    for phi in cols:
        z, segments = _column_nodes(phi, h, count)
        zs.append(z)
        columns.append(segments)
        count += len(z)
    cells = [c for a, b in zip(columns[:-1], columns[1:]) for seg in range(4)
             for c in zip_strip(a[seg], b[seg])]
    anchors = {name: np.array([c[seg][end] for c in columns])
               for name, seg, end in (("bottom", 0, 0), ("front_lower", 0, -1),
                                      ("slit_lower", 1, -1), ("slit_upper", 2, 0),
                                      ("front_upper", 2, -1), ("top", 3, -1))}
    phi = np.repeat(cols, [len(z) for z in zs])
    corner = np.flatnonzero(np.isclose(np.abs(cols), shape.PHI_CORNER))
    return SurfaceGrid(phi, np.concatenate(zs), np.array(cells), anchors, cols,
                       (int(corner[0]), int(corner[1])))
