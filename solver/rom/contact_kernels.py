"""Numba helpers of the reduced contact (solver.rom.contact): geometry and bookkeeping only.

The contact law itself stays in solver.core.kernels.contact, called from Python: a cached
numba function that called those kernels would keep their compiled code when that file
changes (numba's cache checks only the caller's own file), so nothing here calls them.
"""

import numpy as np
from numba import njit

from solver.core import _cache  # noqa: F401  (the solver's kernel cache, before any @njit)


@njit(cache=True)
def slave_positions(q, X, Vs, x_ref, sel, x, xs):
    """x (s, 3) = X + Vs q over all slaves (Vs (s, 3, r)), xs (m, 3) = x[sel]; returns the
    largest distance of a slave from x_ref (s, 3) (inf when x_ref is empty)."""
    s, _, r = Vs.shape
    move = 0.0
    for i in range(s):
        d2 = 0.0
        for c in range(3):
            acc = X[i, c]
            for j in range(r):
                acc += Vs[i, c, j] * q[j]
            x[i, c] = acc
            if x_ref.shape[0] == s:
                d2 += (acc - x_ref[i, c]) ** 2
        move = max(move, d2)
    for t in range(sel.shape[0]):
        for c in range(3):
            xs[t, c] = x[sel[t], c]
    return np.sqrt(move) if x_ref.shape[0] == s else np.inf


@njit(cache=True)
def _triangle_d2(p, xv, ia, ib, ic):
    """Squared distance from p (3,) to the triangle (xv[ia], xv[ib], xv[ic]) (Ericson,
    Real-Time Collision Detection 5.1.5), in scalars."""
    ax, ay, az = xv[ia, 0], xv[ia, 1], xv[ia, 2]
    abx, aby, abz = xv[ib, 0] - ax, xv[ib, 1] - ay, xv[ib, 2] - az
    acx, acy, acz = xv[ic, 0] - ax, xv[ic, 1] - ay, xv[ic, 2] - az
    apx, apy, apz = p[0] - ax, p[1] - ay, p[2] - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz
    bpx, bpy, bpz = apx - abx, apy - aby, apz - abz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        ex, ey, ez = apx - t * abx, apy - t * aby, apz - t * abz
        return ex * ex + ey * ey + ez * ez
    cpx, cpy, cpz = apx - acx, apy - acy, apz - acz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cpx * cpx + cpy * cpy + cpz * cpz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        ex, ey, ez = apx - t * acx, apy - t * acy, apz - t * acz
        return ex * ex + ey * ey + ez * ez
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        ex = bpx - t * (acx - abx)
        ey = bpy - t * (acy - aby)
        ez = bpz - t * (acz - abz)
        return ex * ex + ey * ey + ez * ez
    den = 1.0 / (va + vb + vc)
    v, w = vb * den, vc * den
    ex, ey, ez = apx - v * abx - w * acx, apy - v * aby - w * acy, apz - v * abz - w * acz
    return ex * ex + ey * ey + ez * ez


@njit(cache=True)
def centroids_radii(xv, tris, cen, rad):
    """cen (t, 3) the centroids of the triangles tris (t, 3) over xv and rad (t,) their
    bounding radii (largest centroid-vertex distance), for short_lists."""
    for t in range(tris.shape[0]):
        for i in range(3):
            cen[t, i] = (xv[tris[t, 0], i] + xv[tris[t, 1], i] + xv[tris[t, 2], i]) / 3.0
        r2 = 0.0
        for a in range(3):
            d2 = 0.0
            for i in range(3):
                d2 += (xv[tris[t, a], i] - cen[t, i]) ** 2
            r2 = max(r2, d2)
        rad[t] = np.sqrt(r2)


@njit(cache=True)
def short_lists(x, cen, rad, xv, tris, delta, depth, ptr, out, dist):
    """Candidate lists of the points x (s, 3) on the triangles tris (t, 3) over xv, with
    centroids cen (t, 3) and bounding radii rad (t,) (largest centroid-vertex distance):
    dist (s,) the distance of each point to the surface; the list of point i (out[ptr[i]:
    ptr[i + 1]]) holds the triangles within dist_i + 2 delta of it (empty when dist_i -
    delta > depth; the bounding spheres, |x_i - cen_t| <= dist_i + 2 delta + rad_t, screen
    them first)."""
    s, t = x.shape[0], cen.shape[0]
    rmax = rad.max()
    dc = np.empty(t)
    ptr[0] = 0
    for i in range(s):
        p = x[i]
        best = np.inf
        for k in range(t):
            d = np.sqrt((p[0] - cen[k, 0]) ** 2 + (p[1] - cen[k, 1]) ** 2
                        + (p[2] - cen[k, 2]) ** 2)
            dc[k] = d
            best = min(best, d)
        # the nearest triangle has its centroid within (nearest centroid) + its radius
        d2 = np.inf
        for k in range(t):
            if dc[k] <= best + rmax:
                d2 = min(d2, _triangle_d2(p, xv, tris[k, 0], tris[k, 1], tris[k, 2]))
        d = np.sqrt(d2)
        dist[i] = d
        n = 0
        if d - delta <= depth:
            lim = d + 2.0 * delta
            for k in range(t):
                if dc[k] <= lim + rad[k] and _triangle_d2(
                        p, xv, tris[k, 0], tris[k, 1], tris[k, 2]) <= lim * lim:
                    out[ptr[i] + n] = k
                    n += 1
        ptr[i + 1] = ptr[i] + n


@njit(cache=True)
def mirror_normals(en, me_t, me_j, vn, mv):
    """On a half model's mirror edges (me_t, me_j) and vertices mv: the pseudo-normals of
    the surface with its mirror image, x component zeroed and renormalised (as
    solver.face.terms.contact.surfaces.Normals.update does after surface_normals)."""
    for k in range(me_t.shape[0]):
        n = en[me_t[k], me_j[k]]
        n[0] = 0.0
        s = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        n[0], n[1], n[2] = n[0] / s, n[1] / s, n[2] / s
    for k in range(mv.shape[0]):
        n = vn[mv[k]]
        n[0] = 0.0
        s = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        n[0], n[1], n[2] = n[0] / s, n[1] / s, n[2] / s


@njit(cache=True)
def fill_positions(q, X, Vc, nodes, x):
    """x[nodes] = X[nodes] + V q at the nodes (m,) (Vc (m, 3, r) their basis rows)."""
    r = Vc.shape[2]
    for t in range(nodes.shape[0]):
        i = nodes[t]
        for c in range(3):
            acc = X[i, c]
            for j in range(r):
                acc += Vc[t, c, j] * q[j]
            x[i, c] = acc


@njit(cache=True)
def _project_block(Vb, fe, ke, b, need_k, fr, kr, kv, tmp):
    """fr += Vb[b]^T fe[b]; with need_k, kr += Vb[b]^T ke[b] Vb[b] (kv (d, r), tmp (r, r)
    work; the products by BLAS)."""
    r, d = Vb.shape[2], Vb.shape[1]
    for c in range(d):
        x = fe[b, c]
        if x != 0.0:
            for j in range(r):
                fr[j] += x * Vb[b, c, j]
    if not need_k:
        return
    np.dot(ke[b], Vb[b], kv)
    np.dot(Vb[b].T, kv, tmp)
    for i in range(r):
        for j in range(r):
            kr[i, j] += tmp[i, j]


@njit(cache=True)
def project_pairs(Vb, fe, ke, active, force, need_k, fr, kr, kv):
    """Adds V_b^T f_b (and V_b^T K_b V_b) of the blocks b = active[i] >= 0 (Vb (p, d, r),
    fe (p, d), ke (p, d, d), kv (d, r) work). Returns (the sum of force, a signature of the
    active set: a hash, equal for equal sets)."""
    sig = np.int64(active.shape[0])
    tmp = np.empty((kr.shape[0], kr.shape[1]) if need_k else (0, 0))
    for i in range(active.shape[0]):
        b = active[i]
        if b < 0:
            continue
        sig = sig * np.int64(1099511628211) + b + 1
        _project_block(Vb, fe, ke, b, need_k, fr, kr, kv, tmp)
    total = 0.0
    for i in range(force.shape[0]):
        total += force[i]
    return total, sig


@njit(cache=True)
def project_slaves(Vb, fe, ke, gap, force, need_k, fr, kr, kv):
    """project_pairs for node blocks b with gap[b] <= 0 (in contact)."""
    sig = np.int64(gap.shape[0])
    tmp = np.empty((kr.shape[0], kr.shape[1]) if need_k else (0, 0))
    for b in range(gap.shape[0]):
        if not gap[b] <= 0.0:
            continue
        sig = sig * np.int64(1099511628211) + b + 1
        _project_block(Vb, fe, ke, b, need_k, fr, kr, kv, tmp)
    total = 0.0
    for i in range(force.shape[0]):
        total += force[i]
    return total, sig
