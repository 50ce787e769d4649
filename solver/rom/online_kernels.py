r"""Allocation-free numba kernels of the online reduced step (solver.rom.online).

Each kernel does one thing and is dispatched once per evaluation from Python.

* ``brick_forces_nodal``: the cubature's internal force only (no tangent), on the b
  nodes of its bricks: f = sum_e w_e (f_e(u_e) + s_e f^s_e(u_e)) (b, 3), whose projection
  V_b^T f (one BLAS product, as u = V_b q + L_b before it) is the reduced force, the same
  quantity as solver.rom.kernels.reduced_bricks(need_k=False). Projecting once on the b
  nodes instead of per brick (8 k node rows, about three times b) reads the basis a
  third as often. The tissue and the stiffening brick
  share F at each Gauss point; both energies are Mooney-Rivlin isochoric energies linear
  in (c10, c01, c20, c11, c02), so their forces are one law's with the coefficients added
  (the stiffening has no volumetric part): the core's element force,
  solver.core.kernels.brick_residual.element_residual (inlined into these kernels).
* ``cable_forces_r``: every cable, reduced: x_q - x_p = d0_c + D_c q,
  f_r = sum_c T_c D_c^T n_c, and optionally W_c D_c, W_c = AE/L0 n n^T + T/l (1 - n n^T)
  (solver.core.kernels.cable's law), for the tangent K_r = sum_c D_c^T W_c D_c as one
  BLAS product.
* ``project_nodal``: f_r += sum_i V_i^T f_i and K_r += sum_i V_i^T K_i V_i over the rows i
  of a set of node blocks whose force is non-zero (contact).
* ``brick_forces_full``: the same brick forces unreduced, on the whole mesh (the trust
  check's full-order residual).
* the damping (K_n, the passive small-strain stiffness on a shape): solver.rom.
  damping_kernels, except the matrix-free damping force, which brick_forces_nodal adds.
"""

import numpy as np
from numba import njit

from solver.core.kernels.brick_residual import element_residual

_FM = {"contract", "reassoc", "arcp"}          # no nnan / ninf: NaN and inf checks stay


@njit(cache=True)
def _combined(p, ps, s, out):
    """out (6,) = the Mooney-Rivlin coefficients of tissue p (6,) and stiffening ps (6,)
    at factor s - 1 (clipped at 0) in one: both energies are linear in (c10 ... c02), so
    their stresses add; d (out[5]) is the tissue's (the stiffening has no volumetric
    part)."""
    se = s if s > 0.0 else 0.0
    for c in range(5):
        out[c] = p[c] + se * ps[c]
    out[5] = p[5]


@njit(cache=True, fastmath=_FM)
def brick_forces_nodal(u, conn, w, dndX, wgp, params, sparams, s, form, ue_n, bd, dxn, wn,
                       dvn, D0, kvol, fn):
    """Fills fn (b, 3) with the cubature's weighted nodal forces sum_e w_e (f_e(u_e) +
    s_e f^s_e(u_e)) at the displacements u (b, 3) of the bricks' nodes (V q + L on them;
    conn (k, 8) the bricks' local node indices into u), w (k,), dndX (k, 8, 8, 3), wgp
    (k, 8), params (k, 6) of the tissue (form 0: mean dilatation, 1: full), sparams (k, 6)
    the unit stiffening (c10, c20 used), s (k,) factors - 1. With bd != 0, adds the damping
    force bd K_n,e (u_e - ue_n) of the bricks (ue_n (k, 24) the displacements at the start
    of the substep; K_n on the shape of damping_geometry: dxn, wn, dvn; D0 (k, 6, 6), kvol
    (k,): see solver.rom.damping_kernels). The reduced force is V_b^T fn (the caller's
    BLAS product). Returns the smallest det F (<= 0 or NaN: an inverted brick; fn is then
    partial)."""
    k = conn.shape[0]
    fn[:, :] = 0.0
    ue = np.empty(24)
    due = np.empty(24)
    fe = np.empty(24)
    dv = np.empty(24)
    pe = np.empty(6)
    eps = np.empty(6)
    sg = np.empty(6)
    damp = bd != 0.0
    jmin = np.inf
    for e in range(k):
        for a in range(8):
            n = conn[e, a]
            for i in range(3):
                c = 3 * a + i
                ue[c] = u[n, i]
                due[c] = u[n, i] - ue_n[e, c]
        _combined(params[e], sparams[e], s[e], pe)
        _, jm = element_residual(ue, dndX[e], wgp[e], pe, form, fe, dv)
        if not jm > 0.0:
            return jm
        if jm < jmin:
            jmin = jm
        if damp:
            _damping_force(e, due, dxn, wn, dvn, D0, kvol, form, bd, eps, sg, fe)
        we = w[e]
        for a in range(8):
            n = conn[e, a]
            for i in range(3):
                fn[n, i] += we * fe[3 * a + i]
    return jmin


@njit(cache=True, fastmath=_FM)
def brick_forces_full(u, bricks, dndX, wgp, params, sparams, s, form, out):
    """out (n, 3) += the unreduced forces of the bricks (m, 8) at u (n, 3): tissue and
    stiffening (sparams, s as brick_forces_r, per brick). Returns the smallest det F."""
    ue = np.empty(24)
    fe = np.empty(24)
    dv = np.empty(24)
    pe = np.empty(6)
    jmin = np.inf
    for e in range(bricks.shape[0]):
        for a in range(8):
            for i in range(3):
                ue[3 * a + i] = u[bricks[e, a], i]
        _combined(params[e], sparams[e], s[e], pe)
        _, jm = element_residual(ue, dndX[e], wgp[e], pe, form, fe, dv)
        if not jm > 0.0:
            return jm
        if jm < jmin:
            jmin = jm
        for a in range(8):
            for i in range(3):
                out[bricks[e, a], i] += fe[3 * a + i]
    return jmin


@njit(cache=True, fastmath=_FM)
def _damping_force(e, due, dxn, wn, dvn, D0, kvol, form, bd, eps, sg, fe):
    """fe (24,) += bd K_n,e due (the small-strain stiffness on the shape of dxn, wn)."""
    vol = 0.0
    for g in range(8):
        G = dxn[e, g]
        e0 = e1 = e2 = e3 = e4 = e5 = 0.0
        for a in range(8):
            g0, g1, g2 = G[a, 0], G[a, 1], G[a, 2]
            u0, u1, u2 = due[3 * a], due[3 * a + 1], due[3 * a + 2]
            e0 += g0 * u0
            e1 += g1 * u1
            e2 += g2 * u2
            e3 += g1 * u0 + g0 * u1
            e4 += g2 * u1 + g1 * u2
            e5 += g2 * u0 + g0 * u2
        eps[0], eps[1], eps[2], eps[3], eps[4], eps[5] = e0, e1, e2, e3, e4, e5
        c = bd * wn[e, g]
        for p in range(6):
            acc = 0.0
            for t in range(6):
                acc += D0[e, p, t] * eps[t]
            sg[p] = c * acc
        for a in range(8):
            g0, g1, g2 = G[a, 0], G[a, 1], G[a, 2]
            fe[3 * a] += g0 * sg[0] + g1 * sg[3] + g2 * sg[5]
            fe[3 * a + 1] += g1 * sg[1] + g0 * sg[3] + g2 * sg[4]
            fe[3 * a + 2] += g2 * sg[2] + g1 * sg[4] + g0 * sg[5]
        vol += wn[e, g]
    if form == 0:
        acc = 0.0
        for c in range(24):
            acc += dvn[e, c] * due[c]
        acc *= bd * kvol[e] / vol
        for c in range(24):
            fe[c] += acc * dvn[e, c]


@njit(cache=True, fastmath=_FM)
def cable_forces_r(q, D, d0, AE, L0, e, need_k, add, fr, wd, tension):
    """Reduced cable forces: D (c, 3, r), d0 (c, 3), AE, L0, e (c,) active strains; fills
    (add: adds to) fr (r,), fills tension (c,) and, when need_k, wd (c, 3, r) = W_c D_c,
    W_c = AE/L0 n n^T + T/l (I - n n^T) of a taut cable (0 for a slack one), whose
    product D^T wd (the caller's BLAS product over the 3 c rows) is the tangent
    sum_c D_c^T W_c D_c. Returns a signature of the set of taut cables (a hash: equal
    sets, equal signatures)."""
    nc, _, r = D.shape
    if not add:
        fr[:] = 0.0
    dn = np.empty(r)
    taut = np.int64(nc)
    for c in range(nc):
        x0, x1, x2 = d0[c, 0], d0[c, 1], d0[c, 2]
        for j in range(r):
            qj = q[j]
            x0 += D[c, 0, j] * qj
            x1 += D[c, 1, j] * qj
            x2 += D[c, 2, j] * qj
        l = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        n0, n1, n2 = x0 / l, x1 / l, x2 / l
        st = l / L0[c] - 1.0 + e[c]
        if not st > 0.0:
            tension[c] = 0.0
            if need_k:
                wd[c, :, :] = 0.0
            continue
        taut = taut * np.int64(1099511628211) + c + 1
        T = AE[c] * st
        tension[c] = T
        for j in range(r):
            dn[j] = D[c, 0, j] * n0 + D[c, 1, j] * n1 + D[c, 2, j] * n2
            fr[j] += T * dn[j]
        if need_k:
            a = AE[c] / L0[c] - T / l
            b = T / l
            for j in range(r):
                wd[c, 0, j] = a * n0 * dn[j] + b * D[c, 0, j]
                wd[c, 1, j] = a * n1 * dn[j] + b * D[c, 1, j]
                wd[c, 2, j] = a * n2 * dn[j] + b * D[c, 2, j]
    return taut


@njit(cache=True, fastmath=_FM)
def project_nodal(Vb, fe, ke, rows, need_k, fr, kr):
    """Adds to fr (r,) sum_b Vb[b]^T fe[b] and, when need_k, to kr (r, r)
    sum_b Vb[b]^T ke[b] Vb[b] over the blocks b in rows (m,) (negative entries skipped):
    Vb (p, d, r) basis rows of each block's d DOFs, fe (p, d), ke (p, d, d)."""
    r = Vb.shape[2]
    d = Vb.shape[1]
    kv = np.empty((d, r))
    for t in range(rows.shape[0]):
        b = rows[t]
        if b < 0:
            continue
        for c in range(d):
            x = fe[b, c]
            if x != 0.0:
                for j in range(r):
                    fr[j] += x * Vb[b, c, j]
        if not need_k:
            continue
        for c in range(d):
            for j in range(r):
                kv[c, j] = 0.0
            for c2 in range(d):
                x = ke[b, c, c2]
                if x != 0.0:
                    for j in range(r):
                        kv[c, j] += x * Vb[b, c2, j]
        for c in range(d):
            for i in range(r):
                x = Vb[b, c, i]
                if x != 0.0:
                    for j in range(r):
                        kr[i, j] += x * kv[c, j]


@njit(cache=True)
def lu_solve_small(lu, piv, b, x):
    """x (r,) = -J^-1 b from LAPACK's getrf factors of J (scipy.linalg.lu_factor: lu (r, r),
    L unit lower and U upper in one, piv (r,) the row swaps, 0-based): the Newton
    correction, without the dispatch of a library call (r is a few dozen)."""
    r = b.shape[0]
    for i in range(r):
        x[i] = -b[i]
    for i in range(r):                     # the row swaps, in order
        p = piv[i]
        if p != i:
            t = x[i]
            x[i] = x[p]
            x[p] = t
    for i in range(r):                     # L y = P b, unit diagonal
        acc = x[i]
        for j in range(i):
            acc -= lu[i, j] * x[j]
        x[i] = acc
    for i in range(r - 1, -1, -1):         # U x = y
        acc = x[i]
        for j in range(i + 1, r):
            acc -= lu[i, j] * x[j]
        x[i] = acc / lu[i, i]
