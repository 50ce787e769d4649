"""Penalty laws of one contact pair, given its closest-point geometry (.geometry): the
smoothed penalty psi(p) (penalty_law) and a pair's energy, force and tangent
(pair_penalty); beyond a free boundary, the law faded over a length (boundary_penalty;
faded_pair on a deformable triangle, by complex steps with its face normal held fixed);
in the region of a free vertex, the lip law over the vertex's fan (vertex_fan,
vertex_pair). Each fills one pair's blocks fe, ke; the loops over slaves that call them
are in .assembly. Derivation: the package docstring.
"""

import numpy as np
from numba import njit

from solver.core.kernels.contact.geometry import distance_derivatives, EDGE, FACE, VERTEX


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
