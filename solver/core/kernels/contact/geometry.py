"""Closest-point geometry of node-on-triangle contact: a triangle's closest point to a point
(its feature, face, edge or vertex, and barycentric weights: closest_point), the nearest
candidate and the side of it (nearest, locate, signed_gaps), face, edge and vertex
(pseudo-)normals (surface_normals), the derivatives of the distance over the slave and the
triangle (distance_derivatives), the fade's normal at a rim (rim_normal) and the small
queries of the lip term (extend_points, min_facing, pair_distances).

No penalty here: the laws (solver.core.kernels.contact.laws) and the loops over slaves
(.assembly) build on these. Derivation: the package docstring.
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
