"""Muscle fibres and rigid teeth of the generic face, in the parameters (phi, z, w).

Each fibre is a polyline of control points (phi in degrees, z in mm, w the fraction of the
tissue thickness), sampled at equal arc length into its cable nodes and mapped by
generic_shape.position: the same points at every mesh level. Fibres are defined on the
right side (phi > 0) and mirrored. Courses after the anatomy texts: the orbicularis rings
run from the mid-line to the modiolus just lateral to the mouth corner, where risorius,
zygomaticus, levator anguli oris, buccinator and depressor anguli oris converge; their
other ends lie deep (w = 0.05, just off the skull) in the fixed region, where `insertion`
is True: the last point, except for the mentalis, which runs from the incisive fossa of
the mandible (its first point, the insertion) down into the skin of the chin. The
orbicularis (OOP, OOM) has no bony insertion.

Teeth: the skull surface moved back by TEETH_DEPTH over |phi| <= TEETH_PHI (lips and
cheeks, to the pterygomandibular raphe), the upper arch from TEETH_OVERLAP below the
slit row to TEETH_REACH above it, the lower arch mirrored in z. The same band is the
free (non-fixed) skull-side surface of the tissue: is_free.
"""

import numpy as np

from solver.face.anatomy import generic_shape as shape
from solver.face.anatomy.base import Fibre, RigidSurface

_Z = shape.Z_SLIT
_MODIOLUS = (28.5, _Z, 0.5)
_DEEP = 0.05          # w of a bony insertion: just off the skull surface

# muscle -> fibres: (control points (phi deg, z mm, w), cables, insertion at 'first'/'last'/None)
FIBRES = {
    "LLSAN": [([(7.0, _Z + 12.0, 0.55), (22.0, -52.0, _DEEP)], 6, "last"),
              ([(11.0, _Z + 11.0, 0.55), (25.5, -49.0, _DEEP)], 6, "last")],
    "LAO": [([(26.0, _Z + 4.0, 0.45), (31.0, -50.0, _DEEP)], 9, "last")],
    "ZYG": [([(27.5, _Z + 2.5, 0.55), (50.0, -38.0, _DEEP)], 7, "last"),
            ([(29.0, _Z + 1.0, 0.55), (55.0, -42.0, _DEEP)], 8, "last")],
    "RIS": [([_MODIOLUS, (75.0, -70.5, _DEEP)], 6, "last")],
    "BUC": [([(27.5, _Z + 2.0, 0.3), (62.0, _Z + 6.0, _DEEP)], 6, "last"),
            ([(27.5, _Z - 2.0, 0.3), (62.0, _Z - 3.0, _DEEP)], 6, "last")],
    "DAO": [([(27.5, _Z - 2.5, 0.5), (36.0, -112.0, _DEEP)], 6, "last"),
            ([(26.0, _Z - 3.5, 0.5), (31.0, -114.0, _DEEP)], 6, "last")],
    "DLI": [([(8.0, _Z - 8.0, 0.55), (17.0, -112.0, _DEEP)], 5, "last"),
            ([(13.0, _Z - 7.5, 0.55), (22.0, -111.0, _DEEP)], 6, "last")],
    "MENT": [([(4.0, -100.0, _DEEP), (6.0, -114.0, 0.8)], 5, "first"),
             ([(8.0, -100.0, _DEEP), (11.0, -113.0, 0.8)], 6, "first")],
    "OOP": [([(0.0, _Z + 12.0, 0.45), (16.0, _Z + 10.0, 0.45), _MODIOLUS], 7, None),
            ([(0.0, _Z - 13.0, 0.45), (16.0, _Z - 11.0, 0.45), _MODIOLUS], 7, None)],
    "OOM": [([(0.0, _Z + 3.0, 0.6), (18.0, _Z + 2.5, 0.6), _MODIOLUS], 7, None),
            ([(0.0, _Z - 3.0, 0.6), (18.0, _Z - 2.5, 0.6), _MODIOLUS], 7, None)],
}

TEETH_PHI = np.radians(58.0)    # teeth and free (sliding) inner surface: |phi| below this
TEETH_REACH = 18.0              # free inner surface: within this height of the row line (mm)
TEETH_DEPTH = 0.4               # teeth surface behind the inner tissue surface (mm)
TEETH_MARGIN = 6.0              # the teeth reach this far (mm) past the free inner surface


def _param_points(controls, n_cables):
    """(n_cables + 1, 3) parameters (phi rad, z, w) at equal arc length along the
    physical image of the control polyline."""
    c = np.array(controls, dtype=np.float64)
    c[:, 0] = np.radians(c[:, 0])
    t = np.linspace(0.0, len(c) - 1.0, 200 * (len(c) - 1) + 1)
    dense = np.column_stack([np.interp(t, np.arange(len(c)), c[:, j]) for j in range(3)])
    xyz = shape.position(dense[:, 0], dense[:, 1], dense[:, 2])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))])
    s = np.linspace(0.0, arc[-1], n_cables + 1)
    return np.column_stack([np.interp(s, arc, dense[:, j]) for j in range(3)])


def fibres():
    """All fibres, both sides: per muscle and fibre, the left (x < 0) then the right."""
    out = []
    for muscle, specs in FIBRES.items():
        for controls, n, end in specs:
            p = _param_points(controls, n)
            ins = np.zeros(n + 1, dtype=bool)
            if end is not None:
                ins[0 if end == "first" else -1] = True
            for side, sign in (("left", -1.0), ("right", 1.0)):
                pts = shape.position(p[:, 0], p[:, 1], p[:, 2])
                pts[:, 0] *= sign
                out.append(Fibre(muscle, side, pts, ins.copy()))
    return out


def is_free(phi, z):
    """(k,) bool: inner-surface parameters over the teeth (lips, cheeks), free to slide."""
    return (np.abs(phi) <= TEETH_PHI) & (np.abs(z - shape.row_line(phi)) <= TEETH_REACH)


def _grid_surface(phi, lo, hi, n_z):
    """RigidSurface of the inner surface moved back by TEETH_DEPTH over the band
    lo(phi) <= z <= hi(phi): phi (p,), lo, hi (p,) -> triangles of a p x n_z grid."""
    z = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, n_z)[None, :]
    c, n = shape.inner_curve(phi[:, None], z)
    verts = (c - TEETH_DEPTH * n).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(len(phi) - 1), np.arange(n_z - 1), indexing="ij")
    a = (i * n_z + j).ravel()
    b, d = a + n_z, a + 1
    tris = np.concatenate([np.column_stack([a, b, b + 1]), np.column_stack([a, b + 1, d])])
    return RigidSurface(verts, tris)


def teeth():
    """'upper_teeth', 'lower_teeth': smooth arches behind the lips and cheeks, one surface
    cut along the row line: the arches meet there and share the seam's vertices. They
    reach TEETH_MARGIN past the free inner surface (behind the tissue fixed to the skull
    there), so that a free node sliding along them never passes their outer edge (where a
    slave is released: a force jump).

    One surface rather than two overlapping sheets: where two coincident sheets overlap, a
    lip node near their free edges is pushed by both, then by one, as its nearest point
    crosses an edge: a force jump that makes Newton chatter."""
    reach = TEETH_PHI + TEETH_MARGIN / 70.0        # about TEETH_MARGIN along the arch
    phi = np.linspace(-reach, reach, 2 * int(np.ceil(np.degrees(reach))) + 1)  # 1 deg apart
    r = shape.row_line(phi)
    top = TEETH_REACH + TEETH_MARGIN
    return {"upper_teeth": _grid_surface(phi, r, r + top, 16),
            "lower_teeth": _grid_surface(phi, r - top, r, 16)}
