r"""Lip aperture: the smallest distance between the lips in the mid-sagittal plane.

Each lip's mid-sagittal contour is the chain of its contact-surface edges whose two nodes
lie on the plane x = 0 (the slit face, the vermilion and the inner face over the teeth).
The aperture is the smallest distance in (y, z) between a segment of the upper contour and
one of the lower, and 0 where two segments cross (pressed lips penetrate within the contact
tolerance). For two segments p0 p1 and q0 q1 that do not cross, the distance is the
smallest of the four end-point-to-segment distances, with

    d(a; q0 q1) = |a - q0 - s (q1 - q0)|,   s = clip((a - q0).(q1 - q0) / |q1 - q0|^2, 0, 1);

they cross when each segment's end points lie strictly on both sides of the other's line
(the signs of the cross products differ).

Why not the vertical gap between two landmark nodes: sealed lips can slide past each
other (the lower lip pushed forward of the upper one by OOP and BUC), and their skin-side
edges are then a millimetre apart in z while the slit faces touch.
"""

import numpy as np


def midsagittal_edges(faces, midsagittal):
    """(k, 2) node pairs: the edges of faces (f, 3 or 4; a repeated node marks a wedge)
    with both nodes in midsagittal (node ids), each edge once."""
    faces = np.asarray(faces)
    mid = np.zeros(int(max(faces.max(), np.max(midsagittal))) + 1, dtype=bool)
    mid[np.asarray(midsagittal)] = True
    a = faces.ravel()
    b = np.roll(faces, -1, axis=1).ravel()
    keep = mid[a] & mid[b] & (a != b)
    return np.unique(np.sort(np.stack([a[keep], b[keep]], axis=1), axis=1), axis=0)


def _cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _point_segment(a, q0, q1):
    """Distances (...) from points a to segments q0 q1, all (..., 2)."""
    d = q1 - q0
    s = np.clip(np.einsum("...i,...i", a - q0, d) / np.maximum(
        np.einsum("...i,...i", d, d), 1e-300), 0.0, 1.0)
    return np.linalg.norm(a - q0 - s[..., None] * d, axis=-1)


def contour_gap(yz, upper, lower):
    """Smallest distance (mm) between the segments upper (ku, 2) and lower (kl, 2) (node
    ids into yz (n, 2)); 0 where they cross."""
    p0, p1 = yz[upper[:, 0]][:, None], yz[upper[:, 1]][:, None]        # (ku, 1, 2)
    q0, q1 = yz[lower[:, 0]][None], yz[lower[:, 1]][None]              # (1, kl, 2)
    d1, d2 = _cross(q1 - q0, p0 - q0), _cross(q1 - q0, p1 - q0)
    d3, d4 = _cross(p1 - p0, q0 - p0), _cross(p1 - p0, q1 - p0)
    if np.any((d1 * d2 < 0.0) & (d3 * d4 < 0.0)):
        return 0.0
    return float(min(_point_segment(p0, q0, q1).min(), _point_segment(p1, q0, q1).min(),
                     _point_segment(q0, p0, p1).min(), _point_segment(q1, p0, p1).min()))
