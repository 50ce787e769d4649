"""The loops over slaves: for each slave its nearest candidate (.geometry.locate) and its law
(.laws), into per-slave blocks on a rigid master (rigid_contact; rest_offsets, the offsets
that make the rest state force-free) or per-pair blocks on a deformable one
(surface_contact), with the gaps and normal forces the contact terms report.
"""

import numpy as np
from numba import njit

from solver.core.kernels.contact.geometry import (distance_derivatives, EDGE, FACE, locate,
                                                  rim_normal, VERTEX)
from solver.core.kernels.contact.laws import (boundary_penalty, faded_pair, pair_penalty,
                                              vertex_fan, vertex_pair)


@njit(cache=True)
def rigid_contact(xs, k, xv, tris, ptr, cand, fn, en, vn, free_edge, free_vertex, depth,
                  smooth, need_k, fe, ke, gap, force, tri, fade, rim_other, rim_tri):
    """Slave points xs (s, 3) with stiffness k (s,) on the rigid triangles tris (t, 3) over
    xv (p, 3); candidates of slave i: cand[ptr[i]:ptr[i + 1]]. Fills fe (s, 3), ke (s, 3, 3)
    (zero where inactive), gap (s,) (signed; inf without a candidate or beyond a free
    boundary without fade), force (s,) (N) and tri (s,) (nearest triangle or -1). Active:
    g <= 0 and |g| <= depth. Beyond a free edge or vertex the penalty fades over fade (mm;
    boundary_penalty with rim_normal, whose turn with the point is left out of the force
    and tangent; fade 0: released). Returns the energy."""
    energy = 0.0
    w, wt, xm = np.empty(3), np.empty(3), np.empty((3, 3))
    d, mr, g = np.empty(3), np.empty(3), np.empty(3)
    H, proj = np.empty((3, 3)), np.empty((3, 3))
    for i in range(xs.shape[0]):
        fe[i] = 0.0
        if need_k:
            ke[i] = 0.0
        gap[i], force[i], tri[i] = np.inf, 0.0, -1
        j, region, dist, sd, free, m = locate(xs[i], xv, tris, cand[ptr[i]:ptr[i + 1]], fn,
                                              en, vn, free_edge, free_vertex, w, wt, xm)
        if j < 0:
            continue
        tri[i] = cand[ptr[i] + j]
        if free:                       # beyond a free edge or vertex: no side
            if fade <= 0.0:
                continue
            d[:] = xs[i] - (w[0] * xm[0] + w[1] * xm[1] + w[2] * xm[2])
            rim_normal(d, region, tri[i], tris, xv, fn, vn, rim_other, rim_tri, mr)
            psi, depth_i = boundary_penalty(d, mr, k[i], smooth, fade, need_k, g, H)
            if psi <= 0.0:
                continue
            # proj = dd/dx; fade > 0 holds here: a flag typed like need_k (a literal True
            # would compile another version of distance_derivatives)
            distance_derivatives(xs[i], xm, region, w, fade > 0.0, d, proj)
            fe[i] = proj @ g
            if need_k:
                ke[i] = proj @ H @ proj
            gap[i], force[i] = -depth_i, np.sqrt(fe[i] @ fe[i])
            energy += psi
            continue
        inside = sd <= 0.0
        if (inside and dist > depth) or (not inside and dist >= smooth):
            gap[i] = dist
            continue
        gap[i] = -dist if inside else dist
        psi, force[i] = pair_penalty(xs[i], xm, region, w, dist, inside, m, k[i], smooth,
                                     need_k, fe[i], ke[i])
        energy += psi
    return energy


@njit(cache=True)
def rest_offsets(xs, xv, tris, ptr, cand, fn, en, vn, free_edge, free_vertex, smooth,
                 rim_other, rim_tri, active, out):
    """out (s, 3): for the slaves flagged active (s,) the constant offset that puts xs (s, 3)
    where the law of rigid_contact (same arguments) gives no force: beyond a free edge or
    vertex onto the rim's plane, (a + smooth) m with the depth a behind it and the rim
    normal m; else a gap of smooth along the outward direction n = +-d / |d| (the closest
    point's pseudo-normal where d = 0), (smooth - g) n. Zero for the others."""
    w, wt, xm = np.empty(3), np.empty(3), np.empty((3, 3))
    d, m = np.empty(3), np.empty(3)
    for i in range(xs.shape[0]):
        out[i] = 0.0
        if not active[i]:
            continue
        j, region, dist, sd, free, mp = locate(xs[i], xv, tris, cand[ptr[i]:ptr[i + 1]], fn,
                                               en, vn, free_edge, free_vertex, w, wt, xm)
        if j < 0:
            continue
        d[:] = xs[i] - (w[0] * xm[0] + w[1] * xm[1] + w[2] * xm[2])
        if free:
            rim_normal(d, region, cand[ptr[i] + j], tris, xv, fn, vn, rim_other, rim_tri, m)
            out[i] = (smooth - (m @ d)) * m
            continue
        if dist > 0.0:
            m[:] = d / dist if sd > 0.0 else -d / dist
        else:
            m[:] = mp / np.sqrt(mp @ mp)
        g = dist if sd > 0.0 else -dist
        out[i] = (smooth - g) * m


@njit(cache=True)
def _pair_free(pair_free, p, region):
    """Whether the feature region of pair p lies on its slave's candidate boundary:
    pair_free (p, 3) flags edge j of the pair's triangle; a vertex is free with either of
    the triangle's edges at it."""
    if region == FACE:
        return False
    if region < VERTEX:
        return pair_free[p, region - EDGE]
    v = region - VERTEX
    return pair_free[p, v] or pair_free[p, (v + 2) % 3]


@njit(cache=True)
def _activate(i, p, depth, need_k, fe, kept, gap, force, active):
    """Slave i's pair p is active with a faded penetration depth (mm): its gap, force
    (the norm of the slave's block of fe) and, with need_k, the pair whose ke is kept."""
    if need_k:
        kept[i] = p
    f = fe[p, :3]
    gap[i], force[i], active[i] = -depth, np.sqrt(f @ f), p


NO_PAIR_FREE = np.zeros((0, 3), dtype=np.bool_)     # surface_contact without pair flags


@njit(cache=True)
def surface_contact(x, slaves, k, tris, ptr, pair_tri, fn, en, vn, free_edge, free_vertex,
                    depth, smooth, need_k, fe, ke, gap, force, active, kept, pair_free,
                    fade):
    """Slave nodes slaves (s,) with stiffness k (s,) on deformable triangles tris (t, 3),
    current node positions x (n, 3); the candidate pairs of slave i are
    ptr[i]:ptr[i + 1], with triangles pair_tri (p,). Keeps fe (p, 12), ke (p, 12, 12) zero
    but for each slave's active pair: active (s,) (that pair or -1; fe nonzero there) and
    kept (s,) (the pair whose ke is nonzero or -1) are read and updated. Fills gap (s,),
    force (s,). Active: g <= 0 and |g| <= depth. Beyond a free edge or vertex of the
    surface, or of the slave's candidates (pair_free (p, 3): edge j of the pair's triangle
    borders no other candidate of its slave; NO_PAIR_FREE, (0, 3): no such flags), the
    penalty fades over fade (mm;
    boundary_penalty with the triangle's face normal, its exact gradient and Hessian over
    the slave and the master: faded_pair). Returns the energy."""
    energy = 0.0
    flags = pair_free.shape[0] > 0
    w, wt, xm = np.empty(3), np.empty(3), np.empty((3, 3))
    g, H, d = np.empty(3), np.empty((3, 3)), np.empty(3)
    kmax = 0
    for i in range(slaves.shape[0]):
        kmax = max(kmax, ptr[i + 1] - ptr[i])
    ehat, nrm = np.empty((2 * kmax, 3)), np.empty((2 * kmax, 3))
    efree = np.empty(2 * kmax, dtype=np.bool_)
    for i in range(slaves.shape[0]):
        if active[i] >= 0:
            fe[active[i]] = 0.0
        if need_k and kept[i] >= 0:
            ke[kept[i]] = 0.0
            kept[i] = -1
        gap[i], force[i], active[i] = np.inf, 0.0, -1
        xs = x[slaves[i]]
        cand = pair_tri[ptr[i]:ptr[i + 1]]
        j, region, dist, sd, free, m = locate(xs, x, tris, cand, fn, en, vn, free_edge,
                                              free_vertex, w, wt, xm)
        if j < 0 or dist > depth + fade:
            gap[i] = dist
            continue
        p = ptr[i] + j
        if region >= VERTEX and flags and dist > 1e-12:
            # a vertex: free when any of the slave's candidate edges at it is
            v = tris[pair_tri[p], region - VERTEX]
            K, nf = vertex_fan(v, x, tris, cand, pair_free, ptr[i], fn, ehat, nrm, efree)
            if nf > 0 or free:
                d[:] = xs - x[v]
                if nf == 0:                       # a rim vertex of a candidate-free fan
                    for q in range(K):
                        efree[q] = True
                psi, depth_i = vertex_pair(d, region - VERTEX, ehat, nrm, efree, K, vn[v],
                                           k[i], smooth, fade, need_k, fe[p], ke[p])
                if psi <= 0.0 or depth_i > depth:
                    fe[p] = 0.0
                    if need_k:
                        ke[p] = 0.0
                    gap[i] = dist
                    continue
                _activate(i, p, depth_i, need_k, fe, kept, gap, force, active)
                energy += psi
                continue
            free = False
        elif flags and region != FACE:
            free = free or _pair_free(pair_free, p, region)
        if free:                       # the faded penalty on the triangle's plane
            d[:] = xs - (w[0] * xm[0] + w[1] * xm[1] + w[2] * xm[2])
            # (its H is not used here; need_k rather than False keeps one compiled version)
            psi, depth_i = boundary_penalty(d, fn[pair_tri[p]], k[i], smooth, fade, need_k,
                                            g, H)
            if psi <= 0.0 or depth_i > depth:
                gap[i] = dist
                continue
            faded_pair(xs, xm, region, k[i], smooth, fade, need_k, fe[p], ke[p])
            _activate(i, p, depth_i, need_k, fe, kept, gap, force, active)
            energy += psi
            continue
        inside = sd <= 0.0
        if (inside and dist > depth) or (not inside and dist >= smooth):
            gap[i] = dist
            continue
        gap[i], active[i] = (-dist if inside else dist), p
        if need_k:
            kept[i] = p
        psi, force[i] = pair_penalty(xs, xm, region, w, dist, inside, m, k[i], smooth,
                                     need_k, fe[p], ke[p])
        energy += psi
    return energy
