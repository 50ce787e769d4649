r"""Node-on-triangle-surface penalty contact (see solver.terms.contact for the model).

Closest point. For a slave point x and a triangle (x_1, x_2, x_3), the closest point is
c = sum_a w_a x_a (barycentric weights w, Ericson's region test) on one feature: the face
(region 0), an edge j = (j, j+1 mod 3) (region 1 + j) or a vertex j (region 4 + j).
Locally c minimises f = 1/2 |x - c(xi)|^2 over the feature's affine hull, c(xi) = x_o +
sum_i xi_i tau_i with tangents tau_i (two on a face, one on an edge, none on a vertex).

Energy and derivatives. With d = x - c, F = 1/2 |d|^2 and the stacked nodes
X = (x, x_1, x_2, x_3), weights N = (1, -w_1, -w_2, -w_3), envelope theorem:

    dF/dX_a = N_a d,
    d2F/dX dX = N N^T (x) I - B M^-1 B^T,        M_ij = tau_i . tau_j,
    B_i[a] = -C_ia d - N_a tau_i                 (3-vector block of node a),

where tau_i = sum_a C_ia X_a. This is exact, includes the rotation of the face normal and
the motion of the closest point, and needs no division by |d|. For a rigid master only
the slave block is kept: d2F/dx dx = I - sum_ij tau_i M^-1_ij tau_j, which is n n on a
face, I - t t on an edge and I at a vertex.

Side. The signed gap is g = -|d| when (x - c) . N_f <= 0 for the pseudo-normal N_f of the
closest feature (face normal, mean of the two face normals of an edge, angle-weighted
normal of a vertex), +|d| otherwise; g <= 0 is active (a touching node, g = 0, carries
stiffness but no force). A closest point on a free boundary edge or vertex of an open
surface has no side: such a node is out of contact.
"""

import numpy as np
from numba import njit

FACE, EDGE, VERTEX = 0, 1, 4


@njit(cache=True)
def closest_point(p, a, b, c, w):
    """Closest point of triangle (a, b, c) to p (all (3,)): fills w (3,), returns the region
    (0 face, 1 + j edge j, 4 + j vertex j)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    w[:] = 0.0
    if d1 <= 0.0 and d2 <= 0.0:
        w[0] = 1.0
        return 4
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0.0 and d4 <= d3:
        w[1] = 1.0
        return 5
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        w[0], w[1] = 1.0 - v, v
        return 1
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0.0 and d5 <= d6:
        w[2] = 1.0
        return 6
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        v = d2 / (d2 - d6)
        w[0], w[2] = 1.0 - v, v
        return 3
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        v = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        w[1], w[2] = 1.0 - v, v
        return 2
    s = 1.0 / (va + vb + vc)
    w[1], w[2] = vb * s, vc * s
    w[0] = 1.0 - w[1] - w[2]
    return 0


@njit(cache=True)
def surface_normals(x, tris, nbr, fn, en, vn):
    """Unit face normals fn (t, 3), edge pseudo-normals en (t, 3, 3) (edge j of triangle t;
    the face normal on a free edge) and angle-weighted vertex normals vn (p, 3) of the
    triangles tris (t, 3) over points x (p, 3); nbr (t, 3) is the triangle across edge j
    or -1."""
    vn[:] = 0.0
    for t in range(tris.shape[0]):
        a, b, c = x[tris[t, 0]], x[tris[t, 1]], x[tris[t, 2]]
        n = np.cross(b - a, c - a)
        fn[t] = n / np.sqrt(n @ n)
        for j in range(3):
            p, q, r = x[tris[t, j]], x[tris[t, (j + 1) % 3]], x[tris[t, (j + 2) % 3]]
            e1, e2 = q - p, r - p
            cosang = (e1 @ e2) / np.sqrt((e1 @ e1) * (e2 @ e2))
            vn[tris[t, j]] += np.arccos(min(1.0, max(-1.0, cosang))) * fn[t]
    for t in range(tris.shape[0]):
        for j in range(3):
            m = fn[t].copy()
            if nbr[t, j] >= 0:
                m += fn[nbr[t, j]]
            s = np.sqrt(m @ m)
            en[t, j] = m / s if s > 0.0 else fn[t]
    for v in range(vn.shape[0]):
        s = np.sqrt(vn[v] @ vn[v])
        if s > 0.0:
            vn[v] /= s


@njit(cache=True)
def nearest(p, xv, tris, cand, w):
    """Nearest of the triangles cand (k,) to p (3,): (position in cand or -1, region,
    squared distance); w (3,) gets its barycentric weights."""
    best, region, d2best = -1, 0, np.inf
    wt = np.empty(3)
    for j in range(cand.shape[0]):
        t = cand[j]
        r = closest_point(p, xv[tris[t, 0]], xv[tris[t, 1]], xv[tris[t, 2]], wt)
        c = wt[0] * xv[tris[t, 0]] + wt[1] * xv[tris[t, 1]] + wt[2] * xv[tris[t, 2]]
        d = p - c
        d2 = d @ d
        if d2 < d2best:
            best, region, d2best = j, r, d2
            w[:] = wt
    return best, region, d2best


@njit(cache=True)
def side(p, c, t, region, tris, fn, en, vn, free_edge, free_vertex):
    """(p - c) . pseudo-normal of the feature region of triangle t; NaN on a free
    boundary feature."""
    if region == FACE:
        m = fn[t]
    elif region < VERTEX:
        if free_edge[t, region - EDGE]:
            return np.nan
        m = en[t, region - EDGE]
    else:
        v = tris[t, region - VERTEX]
        if free_vertex[v]:
            return np.nan
        m = vn[v]
    return (p - c) @ m


@njit(cache=True)
def pair_derivatives(x, xm, region, w, k, nloc, need_k, fe, ke):
    """Energy k F of the pair (slave x (3,), master triangle xm (3, 3)) in a region with
    weights w (3,); fe (3 nloc,), ke (3 nloc, 3 nloc) get its gradient and Hessian over
    the slave (nloc = 1, rigid master) or the slave and the triangle (nloc = 4)."""
    d = x - (w[0] * xm[0] + w[1] * xm[1] + w[2] * xm[2])
    nw = np.array([1.0, -w[0], -w[1], -w[2]])
    for a in range(nloc):
        for i in range(3):
            fe[3 * a + i] = k * nw[a] * d[i]
    if not need_k:
        return 0.5 * k * (d @ d)
    # tangents tau_i = sum_a C[i, a] X_a of the feature (over X = slave, x_1, x_2, x_3)
    C = np.zeros((2, 4))
    if region == FACE:
        nt = 2
        C[0, 1], C[0, 2] = -1.0, 1.0
        C[1, 1], C[1, 3] = -1.0, 1.0
    elif region < VERTEX:
        nt = 1
        j = region - EDGE
        C[0, 1 + j], C[0, 1 + (j + 1) % 3] = -1.0, 1.0
    else:
        nt = 0
    tau = np.zeros((2, 3))
    for i in range(nt):
        for a in range(3):
            tau[i] += C[i, 1 + a] * xm[a]
    Minv = np.zeros((2, 2))
    if nt == 2:
        m00, m01, m11 = tau[0] @ tau[0], tau[0] @ tau[1], tau[1] @ tau[1]
        det = m00 * m11 - m01 * m01
        Minv[0, 0], Minv[0, 1], Minv[1, 0], Minv[1, 1] = m11 / det, -m01 / det, -m01 / det, m00 / det
    elif nt == 1:
        Minv[0, 0] = 1.0 / (tau[0] @ tau[0])
    n = 3 * nloc
    B = np.zeros((2, n))
    for i in range(nt):
        for a in range(nloc):
            for q in range(3):
                B[i, 3 * a + q] = -C[i, a] * d[q] - nw[a] * tau[i, q]
    for r in range(n):
        for s in range(n):
            v = nw[r // 3] * nw[s // 3] if r % 3 == s % 3 else 0.0
            for i in range(nt):
                for j in range(nt):
                    v -= B[i, r] * Minv[i, j] * B[j, s]
            ke[r, s] = k * v
    return 0.5 * k * (d @ d)


@njit(cache=True)
def rigid_contact(xs, k, xv, tris, ptr, cand, fn, en, vn, free_edge, free_vertex, depth,
                  need_k, fe, ke, gap, tri):
    """Slave points xs (s, 3) with stiffness k (s,) on the rigid triangles tris (t, 3) over
    xv (p, 3); candidates of slave i: cand[ptr[i]:ptr[i + 1]]. Fills fe (s, 3), ke (s, 3, 3)
    (zero where inactive), gap (s,) (signed; inf without a candidate or on a free
    boundary) and tri (s,) (nearest triangle or -1). Active: g <= 0 and |g| <= depth.
    Returns the energy."""
    energy = 0.0
    w = np.empty(3)
    xm = np.empty((3, 3))
    for i in range(xs.shape[0]):
        fe[i] = 0.0
        if need_k:
            ke[i] = 0.0
        gap[i], tri[i] = np.inf, -1
        j, region, d2 = nearest(xs[i], xv, tris, cand[ptr[i]:ptr[i + 1]], w)
        if j < 0:
            continue
        t = cand[ptr[i] + j]
        tri[i] = t
        for a in range(3):
            xm[a] = xv[tris[t, a]]
        c = w[0] * xm[0] + w[1] * xm[1] + w[2] * xm[2]
        sd = side(xs[i], c, t, region, tris, fn, en, vn, free_edge, free_vertex)
        dist = np.sqrt(d2)
        if not sd <= 0.0 or dist > depth:
            gap[i] = dist if not np.isnan(sd) else np.inf
            continue
        gap[i] = -dist
        energy += pair_derivatives(xs[i], xm, region, w, k[i], 1, need_k, fe[i], ke[i])
    return energy


@njit(cache=True)
def surface_contact(x, slaves, k, tris, ptr, pair_tri, fn, en, vn, free_edge, free_vertex,
                    depth, need_k, fe, ke, gap, active):
    """Slave nodes slaves (s,) with stiffness k (s,) on deformable triangles tris (t, 3),
    current node positions x (n, 3); the candidate pairs of slave i are
    ptr[i]:ptr[i + 1], with triangles pair_tri (p,). Fills fe (p, 12), ke (p, 12, 12)
    (zero but for each slave's active pair), gap (s,) and active (s,) (the active pair
    or -1). Active: g <= 0 and |g| <= depth. Returns the energy."""
    energy = 0.0
    w = np.empty(3)
    xm = np.empty((3, 3))
    for i in range(slaves.shape[0]):
        for p in range(ptr[i], ptr[i + 1]):
            fe[p] = 0.0
            if need_k:
                ke[p] = 0.0
        gap[i], active[i] = np.inf, -1
        xs = x[slaves[i]]
        j, region, d2 = nearest(xs, x, tris, pair_tri[ptr[i]:ptr[i + 1]], w)
        if j < 0:
            continue
        p = ptr[i] + j
        t = pair_tri[p]
        for a in range(3):
            xm[a] = x[tris[t, a]]
        c = w[0] * xm[0] + w[1] * xm[1] + w[2] * xm[2]
        sd = side(xs, c, t, region, tris, fn, en, vn, free_edge, free_vertex)
        dist = np.sqrt(d2)
        if not sd <= 0.0 or dist > depth:
            gap[i] = dist if not np.isnan(sd) else np.inf
            continue
        gap[i], active[i] = -dist, p
        energy += pair_derivatives(xs, xm, region, w, k[i], 4, need_k, fe[p], ke[p])
    return energy


@njit(cache=True)
def pair_distances(xs, xv, tris, pair_tri, d2):
    """d2 (p,): squared distance of each point xs (p, 3) to its triangle pair_tri (p,)."""
    w = np.empty(3)
    for p in range(xs.shape[0]):
        t = pair_tri[p]
        closest_point(xs[p], xv[tris[t, 0]], xv[tris[t, 1]], xv[tris[t, 2]], w)
        d = xs[p] - (w[0] * xv[tris[t, 0]] + w[1] * xv[tris[t, 1]] + w[2] * xv[tris[t, 2]])
        d2[p] = d @ d
