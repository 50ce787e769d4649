r"""Linearized penetrations of contact slaves: p(X + dX) ~ p + v . dX.

For a slave at distance |d| = |x - c| from its nearest master feature (solver.core.kernels.
contact), the penetration is p = +|d| behind the surface and -|d| in front of it; its
gradient over the stacked nodes X = (x, x_1, x_2, x_3) is v = N (x) u with the weights
N = (1, -w_1, -w_2, -w_3) and u = +-d / |d| the direction of growing penetration (u = -m,
the outward pseudo-normal, where |d| vanishes): the gradient grad p of pair_penalty. On
the pure penalty law the contact stiffness of an active slave is k v v^T but for the
curvature of the distance, so a change of status is a rank-one change of the tangent
(solver.core.contact_update).

Slaves with no candidate, beyond a free boundary (released or faded), or deeper than
depth get p = nan.
"""

import numpy as np
from numba import njit

from solver.core.kernels.contact import locate
from solver.core.kernels.contact.assembly import _pair_free


@njit(cache=True)
def _gradient(x, xm, w, dist, sd, m, v):
    """Fills v (3 nloc,) with grad p (nloc = 1: the slave; 4: the slave and the
    triangle's nodes); returns p."""
    nloc = v.shape[0] // 3
    inside = sd <= 0.0
    if dist > 1e-12:
        sgn = 1.0 if inside else -1.0
        for i in range(3):
            v[i] = sgn * (x[i] - w[0] * xm[0, i] - w[1] * xm[1, i] - w[2] * xm[2, i]) / dist
    else:
        v[0], v[1], v[2] = -m[0], -m[1], -m[2]
    for a in range(1, nloc):
        for i in range(3):
            v[3 * a + i] = -w[a - 1] * v[i]
    return dist if inside else -dist


@njit(cache=True)
def rigid_linear_gaps(xs, xv, tris, ptr, cand, fn, en, vn, free_edge, free_vertex, depth,
                      p, v):
    """Slaves xs (s, 3) on a rigid surface (arguments of rigid_contact): p (s,) and
    v (s, 3)."""
    w, wt, xm = np.empty(3), np.empty(3), np.empty((3, 3))
    for i in range(xs.shape[0]):
        p[i] = np.nan
        v[i] = 0.0
        j, region, dist, sd, free, m = locate(xs[i], xv, tris, cand[ptr[i]:ptr[i + 1]], fn,
                                              en, vn, free_edge, free_vertex, w, wt, xm)
        if j < 0 or free or dist > depth:
            continue
        p[i] = _gradient(xs[i], xm, w, dist, sd, m, v[i])


@njit(cache=True)
def surface_linear_gaps(x, slaves, tris, ptr, pair_tri, fn, en, vn, free_edge, free_vertex,
                        depth, pair_free, p, v, pair):
    """Slaves (s,) on deformable triangles (arguments of surface_contact): p (s,), v (s, 12)
    over (slave, x_1, x_2, x_3) and pair (s,) the nearest candidate pair (-1 where p is
    nan)."""
    w, wt, xm = np.empty(3), np.empty(3), np.empty((3, 3))
    for i in range(slaves.shape[0]):
        p[i], pair[i] = np.nan, -1
        v[i] = 0.0
        xs = x[slaves[i]]
        j, region, dist, sd, free, m = locate(xs, x, tris, pair_tri[ptr[i]:ptr[i + 1]], fn,
                                              en, vn, free_edge, free_vertex, w, wt, xm)
        if j < 0 or dist > depth:
            continue
        if free or _pair_free(pair_free, ptr[i] + j, region):
            continue
        pair[i] = ptr[i] + j
        p[i] = _gradient(xs, xm, w, dist, sd, m, v[i])
