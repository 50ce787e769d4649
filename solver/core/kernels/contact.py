r"""Node-on-triangle-surface penalty contact (see solver.face.terms.contact for the model).

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
normal of a vertex), +|d| otherwise; g <= 0 is active. A closest point on a free boundary
edge or vertex of an open surface has no side: such a node is out of contact on a rigid
master; on a deformable one (and beyond an edge of a slave's candidate set) its penalty
fades out beyond the edge (boundary_penalty: psi(a) phi(l / L) with the depth a behind
the nearest triangle's plane and the distance l beyond it, C1 where it meets the face;
on a deformable master with that plane's normal held fixed in the force, faded_pair;
in a rim vertex's region with a normal blended over the vertex's fan, vertex_pair).

Penalty. With the penetration p = -g (signed: negative outside), psi(p) is k p^2 / 2 =
k F for p >= 0 (pure penalty; a touching node, p = 0, carries the stiffness k hess F but no
force) or, with a smoothing length s > 0, k (p + s)^3 / (12 s) over -s < p < s joined (C2)
to k (p^2 / 2 + s^2 / 6) (penalty_law): the contact begins at a gap s with no stiffness and
no kink. In terms of u = +-d / |d| (the direction of growing penetration) grad psi =
psi' N (x) u and hess psi = psi'' (N (x) u)(N (x) u)^T + (psi' / |d|) (hess F - (N (x) u)
(N (x) u)^T) (pair_penalty); the bracket is O(|d|) on a face, so the last term stays
bounded there; on an edge or a vertex it is taken over max(|d|, s).
"""

import numpy as np
from numba import njit

FACE, EDGE, VERTEX = 0, 1, 4


@njit(cache=True)
def _dot(x, i, y, j, z, k):
    """(x[i] - z[k]) . (y[j] - z[k]) over rows of (., 3) arrays, in scalars."""
    return ((x[i, 0] - z[k, 0]) * (y[j, 0] - z[k, 0]) + (x[i, 1] - z[k, 1]) * (y[j, 1] - z[k, 1])
            + (x[i, 2] - z[k, 2]) * (y[j, 2] - z[k, 2]))


@njit(cache=True)
def closest_point(p, xv, ia, ib, ic, w):
    """Closest point of the triangle (xv[ia], xv[ib], xv[ic]) to the point p (3,): fills
    its barycentric weights w (3,), returns the region (0 face, 1 + j edge j, 4 + j
    vertex j). Ericson, Real-Time Collision Detection, 5.1.5."""
    abx, aby, abz = xv[ib, 0] - xv[ia, 0], xv[ib, 1] - xv[ia, 1], xv[ib, 2] - xv[ia, 2]
    acx, acy, acz = xv[ic, 0] - xv[ia, 0], xv[ic, 1] - xv[ia, 1], xv[ic, 2] - xv[ia, 2]
    apx, apy, apz = p[0] - xv[ia, 0], p[1] - xv[ia, 1], p[2] - xv[ia, 2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    w[0] = w[1] = w[2] = 0.0
    if d1 <= 0.0 and d2 <= 0.0:
        w[0] = 1.0
        return 4
    bpx, bpy, bpz = p[0] - xv[ib, 0], p[1] - xv[ib, 1], p[2] - xv[ib, 2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        w[1] = 1.0
        return 5
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        w[0], w[1] = 1.0 - v, v
        return 1
    cpx, cpy, cpz = p[0] - xv[ic, 0], p[1] - xv[ic, 1], p[2] - xv[ic, 2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
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
def extend_points(x, nodes, weights, out):
    """out (n + c, 3): the points x (n, 3), then c points sum_b weights[v, b]
    x[nodes[v, b]] (nodes, weights (c, b): e.g. a surface's virtual vertices)."""
    n = x.shape[0]
    for i in range(n):
        out[i, 0], out[i, 1], out[i, 2] = x[i, 0], x[i, 1], x[i, 2]
    for v in range(nodes.shape[0]):
        a0 = a1 = a2 = 0.0
        for b in range(nodes.shape[1]):
            w, m = weights[v, b], nodes[v, b]
            a0 += w * x[m, 0]
            a1 += w * x[m, 1]
            a2 += w * x[m, 2]
        out[n + v, 0], out[n + v, 1], out[n + v, 2] = a0, a1, a2


@njit(cache=True)
def surface_normals(x, tris, nbr, verts, fn, en, vn):
    """Unit face normals fn (t, 3), edge pseudo-normals en (t, 3, 3) (edge j of triangle t;
    the face normal on a free edge) and angle-weighted vertex normals vn (p, 3) (rows
    verts (v,), the surface's vertices) of the triangles tris (t, 3) over points x (p, 3);
    nbr (t, 3) is the triangle across edge j or -1."""
    every = np.arange(tris.shape[0])
    mark = np.zeros(vn.shape[0], dtype=np.bool_)
    mark[verts] = True
    surface_normals_part(x, tris, nbr, every, every, verts, mark, every, fn, en, vn)


@njit(cache=True)
def surface_normals_part(x, tris, nbr, faces, ring, verts, mark, edges, fn, en, vn):
    """surface_normals on rows of the surface only: the face normals of the triangles
    faces (f,), the vertex normals of verts (v,) (mark (p,) True on them), summed over
    ring (ascending: every triangle with a vertex in verts, so that each sum is the whole
    surface's, in its order), and the edge pseudo-normals of the triangles edges (e,);
    every other row keeps its value. Exact where the vertices of the other rows'
    triangles have not moved (a rigid motion turns normals too), or where the caller reads
    these rows only."""
    for v in verts:
        vn[v, 0] = vn[v, 1] = vn[v, 2] = 0.0
    for t in faces:
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        e1x, e1y, e1z = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        e2x, e2y, e2z = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        s = np.sqrt(nx * nx + ny * ny + nz * nz)
        fn[t, 0], fn[t, 1], fn[t, 2] = nx / s, ny / s, nz / s
    for t in ring:
        for j in range(3):
            p, q, r = tris[t, j], tris[t, (j + 1) % 3], tris[t, (j + 2) % 3]
            if not mark[p]:
                continue
            cosang = _dot(x, q, x, r, x, p) / np.sqrt(_dot(x, q, x, q, x, p)
                                                      * _dot(x, r, x, r, x, p))
            angle = np.arccos(min(1.0, max(-1.0, cosang)))
            for i in range(3):
                vn[p, i] += angle * fn[t, i]
    for t in edges:
        for j in range(3):
            o = nbr[t, j]
            mx, my, mz = fn[t, 0], fn[t, 1], fn[t, 2]
            if o >= 0:
                mx, my, mz = mx + fn[o, 0], my + fn[o, 1], mz + fn[o, 2]
            s = np.sqrt(mx * mx + my * my + mz * mz)
            if s > 0.0:
                en[t, j, 0], en[t, j, 1], en[t, j, 2] = mx / s, my / s, mz / s
            else:
                en[t, j, 0], en[t, j, 1], en[t, j, 2] = fn[t, 0], fn[t, 1], fn[t, 2]
    for v in verts:
        s = np.sqrt(vn[v, 0] ** 2 + vn[v, 1] ** 2 + vn[v, 2] ** 2)
        if s > 0.0:
            vn[v, 0], vn[v, 1], vn[v, 2] = vn[v, 0] / s, vn[v, 1] / s, vn[v, 2] / s


@njit(cache=True)
def nearest(p, xv, tris, cand, w, wt):
    """Nearest of the triangles cand (k,) to p (3,): (position in cand or -1, region,
    squared distance); w (3,) gets its barycentric weights (wt (3,): work space)."""
    best, region, d2best = -1, 0, np.inf
    for j in range(cand.shape[0]):
        t = cand[j]
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        r = closest_point(p, xv, a, b, c, wt)
        d2 = 0.0
        for i in range(3):
            d = p[i] - wt[0] * xv[a, i] - wt[1] * xv[b, i] - wt[2] * xv[c, i]
            d2 += d * d
        if d2 < d2best:
            best, region, d2best = j, r, d2
            w[0], w[1], w[2] = wt[0], wt[1], wt[2]
    return best, region, d2best


@njit(cache=True)
def locate(p, xv, tris, cand, fn, en, vn, free_edge, free_vertex, w, wt, xm):
    """Nearest of the triangles cand (k,) to p (3,): (position in cand or -1, region,
    distance |d|, side (p - c) . m, free, m) with m (3,) the (pseudo-)normal of the closest
    feature and free whether that feature is a free boundary edge or vertex. Fills w (3,)
    the weights and xm (3, 3) the vertices of the triangle (wt (3,): work space)."""
    j, region, d2 = nearest(p, xv, tris, cand, w, wt)
    m = np.zeros(3)
    if j < 0:
        return j, region, np.inf, np.nan, False, m
    t = cand[j]
    for a in range(3):
        for i in range(3):
            xm[a, i] = xv[tris[t, a], i]
    free = False
    if region == FACE:
        m[:] = fn[t]
    elif region < VERTEX:
        free = free_edge[t, region - EDGE]
        m[:] = en[t, region - EDGE]
    else:
        v = tris[t, region - VERTEX]
        free = free_vertex[v]
        m[:] = vn[v]
    sd = 0.0
    for i in range(3):
        sd += (p[i] - w[0] * xm[0, i] - w[1] * xm[1, i] - w[2] * xm[2, i]) * m[i]
    return j, region, np.sqrt(d2), sd, free, m


@njit(cache=True)
def signed_gaps(xs, xv, tris, ptr, cand, fn, en, vn, free_edge, free_vertex, gap):
    """gap (s,): the signed distance of the points xs (s, 3) to their nearest candidate
    triangle (cand[ptr[i]:ptr[i + 1]]); inf without a candidate or where the closest
    feature is a free boundary (no side)."""
    w, wt, xm = np.empty(3), np.empty(3), np.empty((3, 3))
    for i in range(xs.shape[0]):
        j, region, dist, sd, free, m = locate(xs[i], xv, tris, cand[ptr[i]:ptr[i + 1]], fn,
                                              en, vn, free_edge, free_vertex, w, wt, xm)
        gap[i] = np.inf if j < 0 or free else (-dist if sd <= 0.0 else dist)


@njit(cache=True)
def distance_derivatives(x, xm, region, w, need_k, fe, ke):
    """F = |d|^2 / 2 of the pair (slave x (3,), master triangle xm (3, 3)) in a region with
    weights w (3,); fe (3 nloc,), ke (3 nloc, 3 nloc) get its gradient and Hessian over the
    slave (nloc = 1, rigid master) or the slave and the triangle (nloc = 4). Returns F.
    nloc is read off fe's length, not passed: a constant argument would make numba compile
    one version of this function (and of its callers) per value."""
    nloc = fe.shape[0] // 3
    d = x - (w[0] * xm[0] + w[1] * xm[1] + w[2] * xm[2])
    nw = np.array([1.0, -w[0], -w[1], -w[2]])
    for a in range(nloc):
        for i in range(3):
            fe[3 * a + i] = nw[a] * d[i]
    if not need_k:
        return 0.5 * (d @ d)
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
        Minv[0, 0], Minv[1, 1] = m11 / det, m00 / det
        Minv[0, 1] = Minv[1, 0] = -m01 / det
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
            ke[r, s] = v
    return 0.5 * (d @ d)


@njit(cache=True)
def penalty_law(p, k, smooth):
    """The penalty energy of a signed penetration p (mm; negative: a gap), stiffness k
    (N/mm), smoothed over |p| < smooth (mm): psi = k (p + s)^3 / (12 s) there, k (p^2 / 2 +
    s^2 / 6) for p >= s and 0 for p <= -s (s = smooth; s = 0: k p^2 / 2 for p >= 0).
    Returns (psi, psi', psi'')."""
    if p >= smooth:
        return k * (0.5 * p * p + smooth * smooth / 6.0), k * p, k
    q = p + smooth
    if q <= 0.0:
        return 0.0, 0.0, 0.0
    return k * q ** 3 / (12.0 * smooth), 0.25 * k * q * q / smooth, 0.5 * k * q / smooth


@njit(cache=True)
def pair_penalty(x, xm, region, w, dist, inside, m, k, smooth, need_k, fe, ke):
    """Penalty energy of a pair at distance dist, inside (penetrating) or not, m (3,) the
    outward (pseudo-)normal (see distance_derivatives, penalty_law): fills fe, ke; returns
    (psi, the normal force psi' (N)). With u = +-d / |d| the direction of growing
    penetration, grad p = N (x) u and hess p = (hess F - grad p grad p^T) / |d|. On a face
    the bracket is O(|d|) (the master's rotation; 0 on a rigid face); on an edge or a vertex
    it is not, and there it is taken over max(|d|, smooth): the tangent is exact but for
    the curvature of the distance around an edge or vertex closer than smooth."""
    distance_derivatives(x, xm, region, w, need_k, fe, ke)
    nloc = fe.shape[0] // 3
    sgn = 1.0 if inside else -1.0
    psi, dpsi, ddpsi = penalty_law(sgn * dist, k, smooth)
    if dist > 1e-12:
        u = np.array([fe[0], fe[1], fe[2]]) * (sgn / dist)    # the slave block of grad F is d
    else:
        u = -m
    nw = np.array([1.0, -w[0], -w[1], -w[2]])
    if need_k:
        if dist > 1e-12 and (dist > smooth or region == FACE):
            c = sgn * dpsi / dist
        elif smooth > 0.0:
            c = sgn * dpsi / smooth
        else:
            c = k                                           # the pure law's limit at p = 0
        n = 3 * nloc
        for r in range(n):
            gr = nw[r // 3] * u[r % 3]
            for q in range(n):
                ke[r, q] = c * ke[r, q] + (ddpsi - c) * gr * nw[q // 3] * u[q % 3]
    for r in range(3 * nloc):
        fe[r] = dpsi * nw[r // 3] * u[r % 3]
    return psi, dpsi


@njit(cache=True)
def boundary_penalty(d, m, k, smooth, fade, need_k, g, H):
    """Penalty of a point beyond a free boundary feature, faded over the length fade (mm):
    E = psi(a) phi(l / fade) with the depth a = -m . d behind the feature's plane (normal
    m (3,)), the distance l = |d_perp| beyond it, d_perp = d - (m . d) m, psi the penalty
    law and phi(s) = 1 - 3 s^2 + 2 s^3 (0 for s >= 1). Fills g (3,) dE/dd and H (3, 3)
    d2E/dd2 (if need_k); returns (E, a phi), the second the faded depth reported as the
    penetration (E = 0 where a <= 0 or l >= fade)."""
    a = -(m @ d)
    dp = d + a * m
    l = np.sqrt(dp @ dp)
    s = l / fade
    g[:] = 0.0
    if need_k:
        H[:, :] = 0.0
    if a <= -smooth or (a <= 0.0 and smooth == 0.0) or s >= 1.0:
        return 0.0, a
    phi, q = 1.0 - s * s * (3.0 - 2.0 * s), -6.0 * (1.0 - s)     # q = phi'(s) / s
    psi, dpsi, ddpsi = penalty_law(a, k, smooth)
    f2 = fade * fade
    g[:] = -dpsi * phi * m + psi * q * dp / f2
    if need_k:
        r = 6.0 * psi / (f2 * fade * l) if l > 0.0 else 0.0
        for i in range(3):
            for j in range(3):
                H[i, j] = (ddpsi * phi * m[i] * m[j]
                           - dpsi * q * (m[i] * dp[j] + dp[i] * m[j]) / f2
                           + psi * q * ((1.0 if i == j else 0.0) - m[i] * m[j]) / f2
                           + r * dp[i] * dp[j])
    return psi * phi, a * phi


@njit(cache=True)
def _law_c(p, k, smooth):
    """penalty_law's energy for a complex p (complex-step derivatives; branches on p.real)."""
    if p.real >= smooth:
        return k * (0.5 * p * p + smooth * smooth / 6.0)
    q = p + smooth
    if q.real <= 0.0:
        return 0.0 * p
    return k * q ** 3 / (12.0 * smooth)


@njit(cache=True)
def _faded_energy(X, region, m, k, smooth, fade):
    """boundary_penalty's E = psi(a) phi(l / fade) of the slave X[0] beyond the edge or
    vertex region of the triangle X[1:4] (complex (4, 3)), with the normal m (3,) held
    fixed (the triangle's face normal at the real X) and d = X[0] - c, c the closest point
    of the region's feature (its formula held fixed: the derivatives within the region)."""
    if region < VERTEX:
        xi, xj = X[1 + region - EDGE], X[1 + (region - EDGE + 1) % 3]
        e = xj - xi
        r = X[0] - xi
        c = xi + ((r[0] * e[0] + r[1] * e[1] + r[2] * e[2])
                  / (e[0] * e[0] + e[1] * e[1] + e[2] * e[2])) * e
    else:
        c = X[1 + region - VERTEX]
    d = X[0] - c
    a = -(m[0] * d[0] + m[1] * d[1] + m[2] * d[2])
    dp = d + a * m
    s = np.sqrt(dp[0] * dp[0] + dp[1] * dp[1] + dp[2] * dp[2]) / fade
    if s.real >= 1.0:
        return 0.0 * a
    return _law_c(a, k, smooth) * (1.0 - s * s * (3.0 - 2.0 * s))


@njit(cache=True)
def _face_normal(X):
    """Unit normal of the triangle X[1:4] (real (4, 3))."""
    n = np.cross(X[2] - X[1], X[3] - X[1])
    return n / np.sqrt(n @ n)


@njit(cache=True)
def _faded_gradient(X, region, k, smooth, fade, Xc, g):
    """g (12,) = dE/dX of _faded_energy at the real X (4, 3) by complex steps, with the
    triangle's normal at X held fixed; Xc (4, 3) complex work space."""
    h = 1e-30
    m = _face_normal(X)
    for a in range(4):
        for i in range(3):
            Xc[a, i] = X[a, i]
    for r in range(12):
        a, i = r // 3, r % 3
        Xc[a, i] = X[a, i] + 1j * h
        g[r] = _faded_energy(Xc, region, m, k, smooth, fade).imag / h
        Xc[a, i] = X[a, i]


FADED_STEP = 1e-6       # mm: central differences of the exact gradient for the Hessian


@njit(cache=True)
def faded_pair(xs, xm, region, k, smooth, fade, need_k, fe, ke):
    """The faded penalty of a slave xs (3,) beyond a free edge (region) of the deformable
    triangle xm (3, 3): fe (12,) the force over (slave, x_1, x_2, x_3), the gradient of E
    with the face normal held fixed (the closest point's sliding included, by complex
    steps), and when need_k ke (12, 12) its derivative (central differences over
    FADED_STEP, the normal's turn included), symmetrized. Holding the normal makes the
    force continuous where the region meets a free vertex's (vertex_pair), whose normal
    blends those of several triangles."""
    X = np.empty((4, 3))
    X[0] = xs
    X[1:] = xm
    Xc = np.empty((4, 3), dtype=np.complex128)
    _faded_gradient(X, region, k, smooth, fade, Xc, fe)
    if not need_k:
        return
    gp, gm = np.empty(12), np.empty(12)
    for c in range(12):
        a, i = c // 3, c % 3
        X[a, i] += FADED_STEP
        _faded_gradient(X, region, k, smooth, fade, Xc, gp)
        X[a, i] -= 2.0 * FADED_STEP
        _faded_gradient(X, region, k, smooth, fade, Xc, gm)
        X[a, i] += FADED_STEP
        for r in range(12):
            ke[r, c] = (gp[r] - gm[r]) / (2.0 * FADED_STEP)
    for r in range(12):
        for c in range(r + 1, 12):
            v = 0.5 * (ke[r, c] + ke[c, r])
            ke[r, c] = ke[c, r] = v


@njit(cache=True)
def vertex_fan(v, x, tris, cand, pair_free, p0, fn, ehat, nrm, free):
    """The slave's candidate edges at vertex v: unit directions ehat (K, 3) from v,
    whether each is free for the slave (free (K,): it borders no other candidate, or the
    surface's rim) and, for a free one, its triangle's face normal nrm (K, 3); candidates
    cand (k,) with pair_free rows p0 + j. Returns (K, the number of free edges)."""
    K, nf = 0, 0
    for j in range(cand.shape[0]):
        t = cand[j]
        for a in range(3):
            if tris[t, a] != v:
                continue
            for e, o in ((a, tris[t, (a + 1) % 3]), ((a + 2) % 3, tris[t, (a + 2) % 3])):
                dv = x[o] - x[v]
                ehat[K] = dv / np.sqrt(dv @ dv)
                free[K] = pair_free[p0 + j, e]
                nrm[K] = fn[t]
                nf += free[K]
                K += 1
    return K, nf


ALIGN_LO, ALIGN_HI = 0.3, 0.6    # |cos| of d to the vertex normal: where a vertex's law
                                # turns from the rim's plane to the plain distance


@njit(cache=True)
def _vertex_energy(d, ehat, nrm, free, K, vn, k, smooth, fade):
    """The lip law in the region of a free vertex v: d = x - v (complex (3,)), the fan of
    vertex_fan and the vertex normal vn (3,) held fixed. With alpha_q = -d . ehat_q >= 0
    (the distance from the plane where the region meets edge q's),

        E = psi(a) phi(l / fade),  a = -m . d,  l = |d + a m|,
        m ~ sum_free n_q / alpha_q^2 + c u sum_inner 1 / alpha_q^2,

    u = -sgn d / |d| (sgn = +1 behind vn: inside), c = smoothstep of |d . vn| / |d| over
    [ALIGN_LO, ALIGN_HI]. Where the region meets a free edge's (alpha_q -> 0), m -> n_q:
    that edge's faded law; where it meets an inner edge's, m -> u, so a -> sgn |d| and
    l -> 0: the plain law psi(sgn |d|) of that edge's end; the weights turn m with zero
    slope there, so E is C1 across every boundary of the region. c keeps the plain
    distance out where d runs along the surface (a point beyond a rim's corner, or where
    the side test flips), which no inner edge's region reaches.
    Returns (E, the reported depth a phi)."""
    dist = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    side = d[0] * vn[0] + d[1] * vn[1] + d[2] * vn[2]
    sgn = 1.0 if side.real <= 0.0 else -1.0
    cosv = sgn * -side / dist
    t = (cosv - ALIGN_LO) / (ALIGN_HI - ALIGN_LO)
    if t.real <= 0.0:
        c = 0.0 * t
    elif t.real >= 1.0:
        c = 1.0 + 0.0 * t
    else:
        c = t * t * (3.0 - 2.0 * t)
    m = np.zeros(3, dtype=np.complex128)
    wi = 0.0 * dist
    hit = -1
    for q in range(K):
        al = -(d[0] * ehat[q, 0] + d[1] * ehat[q, 1] + d[2] * ehat[q, 2])
        if al.real <= 1e-14 * dist.real:
            if free[q] or c.real > 0.0:
                hit = q
            continue
        if free[q]:
            for i in range(3):
                m[i] += nrm[q, i] / (al * al)
        else:
            wi += 1.0 / (al * al)
    if hit >= 0 and free[hit]:
        for i in range(3):
            m[i] = nrm[hit, i] + 0.0 * dist
    elif hit >= 0:
        m = -sgn * d / dist
    else:
        m = m - (c * wi * sgn / dist) * d
    m = m / np.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
    a = -(m[0] * d[0] + m[1] * d[1] + m[2] * d[2])
    dp = d + a * m
    s = np.sqrt(dp[0] * dp[0] + dp[1] * dp[1] + dp[2] * dp[2]) / fade
    if s.real >= 1.0:
        return 0.0 * a, 0.0 * a
    phi = 1.0 - s * s * (3.0 - 2.0 * s)
    return _law_c(a, k, smooth) * phi, a * phi


@njit(cache=True)
def _vertex_gradient(d, ehat, nrm, free, K, vn, k, smooth, fade, g):
    """g (3,) = dE/dd of _vertex_energy at the real d (3,) by complex steps; returns (E,
    the reported depth)."""
    h = 1e-30
    dc = np.empty(3, dtype=np.complex128)
    for i in range(3):
        dc[i] = d[i]
    e, depth = _vertex_energy(dc, ehat, nrm, free, K, vn, k, smooth, fade)
    for i in range(3):
        dc[i] = d[i] + 1j * h
        g[i] = _vertex_energy(dc, ehat, nrm, free, K, vn, k, smooth, fade)[0].imag / h
        dc[i] = d[i]
    return e.real, depth.real


@njit(cache=True)
def vertex_pair(d, av, ehat, nrm, free, K, vn, k, smooth, fade, need_k, fe, ke):
    """The lip law of a slave at d = x - v (3,) in the region of a free vertex v, the local
    vertex av of the pair's triangle (_vertex_energy, the fan held fixed): fe (12,) the
    force (dE/dd on the slave, -dE/dd on v), ke (12, 12) when need_k (central differences
    of the gradient over d, symmetrized, on the slave and v). Returns (E, the depth)."""
    g = np.empty(3)
    e, depth = _vertex_gradient(d, ehat, nrm, free, K, vn, k, smooth, fade, g)
    fe[:] = 0.0
    b = 3 * (1 + av)
    for i in range(3):
        fe[i], fe[b + i] = g[i], -g[i]
    if not need_k:
        return e, depth
    H = np.empty((3, 3))
    gp, gm, dd = np.empty(3), np.empty(3), d.copy()
    for c in range(3):
        dd[c] = d[c] + FADED_STEP
        _vertex_gradient(dd, ehat, nrm, free, K, vn, k, smooth, fade, gp)
        dd[c] = d[c] - FADED_STEP
        _vertex_gradient(dd, ehat, nrm, free, K, vn, k, smooth, fade, gm)
        dd[c] = d[c]
        for r in range(3):
            H[r, c] = (gp[r] - gm[r]) / (2.0 * FADED_STEP)
    ke[:, :] = 0.0
    for r in range(3):
        for c in range(3):
            h = 0.5 * (H[r, c] + H[c, r])
            ke[r, c], ke[b + r, b + c] = h, h
            ke[r, b + c], ke[b + r, c] = -h, -h
    return e, depth


@njit(cache=True)
def rim_normal(d, region, t, tris, xv, fn, vn, rim_other, rim_tri, m):
    """The fade's normal m (3,) for a point at d (3,) from its closest point on a free
    edge (region 1 + j of triangle t: the face normal fn[t]) or free vertex v (region
    4 + j): between the face normals of the triangles of v's two free edges (other ends
    rim_other[v], triangles rim_tri[v]), by the point's place in v's region, a1 / (a1 + a2)
    with a_k = d . e_k <= 0 (e_k the unit edge directions from v): fn of the first edge's
    triangle where the region meets that edge's (a1 = 0), of the second's where it meets
    the second's, so that m is continuous around the rim; vn[v] where v has not two."""
    if region < VERTEX:
        m[:] = fn[t]
        return
    v = tris[t, region - VERTEX]
    if rim_other[v, 0] < 0:
        m[:] = vn[v]
        return
    a = np.zeros(2)
    for c in range(2):
        e = xv[rim_other[v, c]] - xv[v]
        a[c] = min(0.0, (d @ e) / np.sqrt(e @ e))
    f = a[0] / (a[0] + a[1]) if a[0] + a[1] < 0.0 else 0.5
    m[:] = (1.0 - f) * fn[rim_tri[v, 0]] + f * fn[rim_tri[v, 1]]
    m /= np.sqrt(m @ m)


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


@njit(cache=True)
def min_facing(ptr, tri_ids, slave_fn, nodes, master_n, out):
    """out (p,): the smallest slave_fn[f] . master_n[p] over the triangles f at node
    nodes[p] (incidence lists ptr (n + 1,), tri_ids), inf for a node on none: negative
    when a face of the slave surface at the node faces the master triangle of normal
    master_n[p] (p, 3)."""
    for p in range(nodes.shape[0]):
        m = np.inf
        for j in range(ptr[nodes[p]], ptr[nodes[p] + 1]):
            f = tri_ids[j]
            d = (slave_fn[f, 0] * master_n[p, 0] + slave_fn[f, 1] * master_n[p, 1]
                 + slave_fn[f, 2] * master_n[p, 2])
            if d < m:
                m = d
        out[p] = m


@njit(cache=True)
def pair_distances(xs, xv, tris, pair_tri, d2):
    """d2 (p,): squared distance of each point xs (p, 3) to its triangle pair_tri (p,)."""
    w = np.empty(3)
    for p in range(xs.shape[0]):
        a, b, c = tris[pair_tri[p], 0], tris[pair_tri[p], 1], tris[pair_tri[p], 2]
        closest_point(xs[p], xv, a, b, c, w)
        d2[p] = 0.0
        for i in range(3):
            d = xs[p, i] - w[0] * xv[a, i] - w[1] * xv[b, i] - w[2] * xv[c, i]
            d2[p] += d * d
