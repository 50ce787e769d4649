"""Parametric surfaces of the generic face (see generic.py for the whole construction).

A point of the tissue has parameters (phi, z, w):
    phi  angle around the face (rad): 0 mid-sagittal, > 0 the subject's right (x > 0),
         |phi| <= PHI_MAX; the sign of phi is the sign of x and every function below
         depends on |phi| only, so the face is exactly symmetric
    z    height, mm (the physical z of the point)
    w    fraction of the tissue thickness: 0 on the skull (inner surface), 1 on the skin

Inner surface (skull, teeth): in each horizontal plane a U-shaped curve C, half an
ellipse (half-width a(z), depth b, front at y = apex(z)) continued straight backwards past
|phi| = 90 deg. Skin: the inner surface pushed out along the curve's horizontal normal
N(phi, z) by the thickness T(phi, z):

    P(phi, z, w) = C(phi, z) + w T(phi, z) N(phi, z).

Through-thickness lines are horizontal, so the map is regular wherever T > 0 and z rises
along a column. T blends a mid-line profile (upper lip, lower lip, mentolabial sulcus,
chin) into a lateral one (cheeks) and adds the vermilion: a roll over a lip edge set back
at the mouth slit, faded out towards the mouth corners. The mask's edges are curves in
(phi, z): bottom_line (chin, jaw line), top_line (under the nose, up beside it to the
temples) and the back edge phi = +-PHI_MAX. Every shape here is independent of the mesh.
"""

from functools import cache

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.optimize import minimize_scalar

Z_SLIT = -80.0            # height of the mouth slit (mm)
SLIT_GAP = 0.4            # lip gap at the mid-line at rest (mm), 0 at the corners
PHI_CORNER = np.radians(23.5)   # mouth corners
PHI_MAX = np.radians(111.63)    # back edge of the face, towards the ears
ROLL_UPPER = 6.0          # height of the upper vermilion roll's crest above the slit (mm)
ROLL_LOWER = 7.0          # depth of the lower vermilion roll's crest below the slit (mm)
SLIT_OPEN = 1.0           # extra opening of each lip's slit edge at the skull side (mm)
SLIT_OPEN_DEPTH = 0.45    # w where the opening has faded out (the inner layer's top)
SLIT_OPEN_REACH = 6.0     # height over which it fades out above and below the slit (mm)

_APEX = PchipInterpolator(   # z -> y of the inner surface on the mid-line
    [-125.0, -120.0, -112.0, -104.0, -96.0, -88.0, -80.0, -72.0, -64.0, -57.0, -40.0,
     -10.0, 15.0],
    [50.0, 56.5, 61.5, 64.5, 67.5, 71.0, 73.0, 73.8, 73.5, 72.5, 70.0, 66.0, 62.0])
_HALF_WIDTH = PchipInterpolator(   # z -> a, half-width of the inner surface
    [-125.0, -110.0, -95.0, -80.0, -60.0, -30.0, 0.0, 15.0],
    [40.0, 46.0, 51.0, 55.0, 58.5, 61.8, 63.76, 63.76])
_TOP = PchipInterpolator(   # |phi| (deg) -> z of the upper edge
    [0.0, 14.0, 20.0, 28.0, 40.0, 55.0, 70.0, 180.0],
    [-57.0, -57.0, -53.0, -42.0, -23.0, -3.0, 13.1, 13.1])
_DEPTH = 74.0               # b, depth of the elliptic front (mm)
_T_MID = PchipInterpolator(   # z -> thickness on the mid-line, without the vermilion
    [-125.0, -118.0, -108.0, -100.0, -95.0, -89.0, -80.0, -70.0, -62.0, -57.0],
    [6.0, 9.0, 12.5, 9.0, 7.5, 10.0, 11.5, 12.5, 13.0, 13.5])


def smoothstep(t):
    """C1 ramp: 0 for t <= 0, 1 for t >= 1, 3t^2 - 2t^3 between."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _gauss(t):
    return np.exp(-t * t)


def row_line(phi):
    """z (mm) of the row through the mouth slit, continued backwards (rising) (k,)."""
    p = np.abs(phi)
    return Z_SLIT + 16.0 * smoothstep((p - PHI_CORNER) / (PHI_MAX - PHI_CORNER))


def top_line(phi):
    """z (mm) of the upper edge: under the nose at the mid-line, up beside the nose and
    over the cheekbone to the temple (k,)."""
    return _TOP(np.degrees(np.abs(phi)))


def bottom_line(phi):
    """z (mm) of the lower edge: the chin, then along the jaw line (k,)."""
    return -124.7 + 30.0 * smoothstep(np.abs(phi) / PHI_MAX)


def in_mouth(phi):
    """(k,) bool: columns strictly between the mouth corners, where the slit cuts."""
    return np.abs(phi) < PHI_CORNER - 1e-12


def slit_gap(phi):
    """Lip gap (mm) along the slit, SLIT_GAP at the mid-line, 0 at the corners (k,)."""
    r = np.abs(phi) / PHI_CORNER
    return SLIT_GAP * np.clip(1.0 - r * r, 0.0, None)


def slit_opening(phi, z, w):
    """Shift in z (mm) of the tissue point (phi, z, w) that opens the slit towards the
    skull, broadcast:

        dz = sign(z - r) SLIT_OPEN (1 - (phi/phi_c)^2)^2 max(0, 1 - w/SLIT_OPEN_DEPTH)
             (1 - smoothstep((|z - r| - g) / SLIT_OPEN_REACH))

    r the slit row, g half the slit gap. Closed lips touch on their outer part, and
    their inner edges stand 2 SLIT_OPEN + SLIT_GAP apart on the mid-line, so that pressed
    and sheared lips do not meet edge to edge (two convex edges passing each other one
    way or the other). 0 at the skin side (w >= SLIT_OPEN_DEPTH), at the mouth corners
    and beyond, and SLIT_OPEN_REACH away from the slit; linear in w, so a column's
    extra nodes through the thickness do not change its volume.
    """
    p = np.abs(phi)
    r, g = row_line(phi), 0.5 * slit_gap(phi)
    d = z - r
    lip = np.clip(1.0 - (p / PHI_CORNER) ** 2, 0.0, None) ** 2
    depth = np.clip(1.0 - np.asarray(w) / SLIT_OPEN_DEPTH, 0.0, None)
    fade = 1.0 - smoothstep((np.abs(d) - g) / SLIT_OPEN_REACH)
    return np.sign(d) * SLIT_OPEN * lip * depth * fade


def inner_curve(phi, z):
    """Inner surface point and horizontal outward normal at (phi, z).

    phi, z broadcastable arrays -> point (..., 3), normal (..., 3) (normal z = 0).
    """
    p = np.abs(phi)
    a, apex = _HALF_WIDTH(z), _APEX(z)
    front = p <= np.pi / 2
    x = np.where(front, a * np.sin(np.minimum(p, np.pi / 2)), a)
    y = apex - _DEPTH + _DEPTH * np.cos(p)
    nx = np.where(front, _DEPTH * np.sin(p), 1.0)
    ny = np.where(front, a * np.cos(p), 0.0)
    norm = np.hypot(nx, ny)
    s = np.where(np.signbit(phi), -1.0, 1.0)
    point = np.stack([s * x, y, np.zeros_like(y) + z], axis=-1)
    normal = np.stack([s * nx / norm, ny / norm, np.zeros_like(y)], axis=-1)
    return point, normal


def _vermilion(zeta):
    """Lip profile term (mm) against the height above the slit zeta (mm), both lips.

    A roll with its crest at zeta = ROLL_UPPER or -ROLL_LOWER over an edge set back at
    the slit; 0 far from the slit.
    """
    up = zeta >= 0
    f = np.where(up, zeta / ROLL_UPPER, -zeta / ROLL_LOWER)
    roll = np.where(up, 2.8, 2.5) * f * np.exp(1.0 - f)
    setback = 3.5 * np.clip(1.0 - f, 0.0, None) ** 2
    return roll - setback


def thickness(phi, z):
    """Tissue thickness T (mm) along the horizontal normal at (phi, z), broadcast."""
    p = np.abs(phi)
    s = p * 60.0                                  # ~ arc length from the mid-line (mm)
    mid = _T_MID(np.clip(z, -125.0, -57.0))
    side = (6.5 + 6.0 * _gauss((s - 52.0) / 20.0) * _gauss((z + 75.0) / 20.0)
            + 1.5 * smoothstep((s - 60.0) / 40.0))
    w = _gauss(s / 26.0)
    lip = np.clip(1.0 - (p / PHI_CORNER) ** 2, 0.0, None) ** 2
    return w * mid + (1.0 - w) * side + lip * _vermilion(z - Z_SLIT)


def position(phi, z, w):
    """Physical point (..., 3) of the parameters phi, z, w (broadcast)."""
    c, n = inner_curve(phi, z)
    t = thickness(phi, z)
    return c + (np.asarray(w) * t)[..., None] * n


@cache
def lip_fronts():
    """(zeta_upper, zeta_lower) (mm, both > 0): heights above and below the slit of the
    most anterior mid-sagittal skin points of the upper and lower lip (vermilion fronts)."""
    def front(sign):
        r = minimize_scalar(lambda zeta: -position(0.0, Z_SLIT + sign * zeta, 1.0)[1],
                            bounds=(1.0, 12.0), method="bounded", options={"xatol": 1e-10})
        return float(r.x)
    return front(1.0), front(-1.0)
