r"""Allocation-free numba kernels of the online reduced step (solver.rom.online).

Each kernel does one thing and is dispatched once per evaluation from Python.

* ``brick_forces_r``: the cubature's reduced internal force only (no tangent),
  f_r = sum_e w_e V_e^T (f_e(u_e) + s_e f^s_e(u_e)), u_e = V_e q + le_e (le: the lifting,
  the prescribed displacements of the jaw, solver.rom.lifting), the same quantity as
  solver.rom.kernels.reduced_bricks(need_k=False), written for speed:
  - the tissue and the stiffening brick share F at each Gauss point; both energies are
    Mooney-Rivlin isochoric energies linear in (c10, c01, c20, c11, c02), so their
    stresses add into one: S = S_iso(p + s_e p^s) (+ S_vol of the tissue, for the
    'full' formulation; the stiffening has d = inf: no volumetric part). Exact;
  - first Piola-Kirchhoff P = F S, so f_ai = sum_g w_g sum_J P_iJ dN_a/dX_J (no B matrix);
  - S = 2 (W_1 1 + W_2 (I1 1 - C) + W_3 adj C) with adj C = I3 C^-1 (solver.core.kernels.
    invariants' chain rule, first derivatives only);
  - mean dilatation: dv/dx_ai = sum_g w_g (dN_a/dX adj F)_i, f += U'(v / V) dv/dx.
* ``cable_forces_r``: every cable, reduced: x_q - x_p = d0_c + D_c q,
  f_r = sum_c T_c D_c^T n_c, and optionally K_r = sum_c D_c^T (AE/L0 n n^T
  + T/l (1 - n n^T)) D_c (solver.core.kernels.cable's law, projected).
* ``project_nodal``: f_r += sum_i V_i^T f_i and K_r += sum_i V_i^T K_i V_i over the rows i
  of a set of node blocks whose force is non-zero (contact).
* ``brick_forces_full``: the same brick forces unreduced, on the whole mesh (the trust
  check's full-order residual).
* the damping (K_n, the passive small-strain stiffness on a shape): solver.rom.
  damping_kernels, except the matrix-free damping force, which brick_forces_r adds.
"""

import numpy as np
from numba import njit

from solver.core import _cache  # noqa: F401  (the solver's kernel cache, before any @njit)

_FM = {"contract", "reassoc", "arcp"}          # no nnan / ninf: NaN and inf checks stay


@njit(cache=True, fastmath=_FM)
def _brick_force(ue, dndX, wgp, m10, m01, m20, m11, m02, d, form, fe, dv):
    """fe (24,) = the brick's internal force at its displacements ue (24,) for the
    Mooney-Rivlin coefficients (m10, m01, m20, m11, m02) and d (module docstring); dv (24,)
    work. Returns the smallest det F (<= 0 or NaN: inverted, fe partial)."""
    for c in range(24):
        fe[c] = 0.0
        dv[c] = 0.0
    jmin = np.inf
    v = 0.0
    V = 0.0
    for g in range(8):
        G = dndX[g]
        wg = wgp[g]
        f00 = 1.0
        f01 = 0.0
        f02 = 0.0
        f10 = 0.0
        f11 = 1.0
        f12 = 0.0
        f20 = 0.0
        f21 = 0.0
        f22 = 1.0
        for a in range(8):
            g0, g1, g2 = G[a, 0], G[a, 1], G[a, 2]
            u0, u1, u2 = ue[3 * a], ue[3 * a + 1], ue[3 * a + 2]
            f00 += u0 * g0
            f01 += u0 * g1
            f02 += u0 * g2
            f10 += u1 * g0
            f11 += u1 * g1
            f12 += u1 * g2
            f20 += u2 * g0
            f21 += u2 * g1
            f22 += u2 * g2
        # adj F (det F F^-1)
        a00 = f11 * f22 - f12 * f21
        a01 = f02 * f21 - f01 * f22
        a02 = f01 * f12 - f02 * f11
        a10 = f12 * f20 - f10 * f22
        a11 = f00 * f22 - f02 * f20
        a12 = f02 * f10 - f00 * f12
        a20 = f10 * f21 - f11 * f20
        a21 = f01 * f20 - f00 * f21
        a22 = f00 * f11 - f01 * f10
        det = f00 * a00 + f01 * a10 + f02 * a20
        if not det > 0.0:
            return det                             # <= 0 or NaN
        if det < jmin:
            jmin = det
        # C = F^T F (symmetric)
        c00 = f00 * f00 + f10 * f10 + f20 * f20
        c11 = f01 * f01 + f11 * f11 + f21 * f21
        c22 = f02 * f02 + f12 * f12 + f22 * f22
        c0_1 = f00 * f01 + f10 * f11 + f20 * f21
        c1_2 = f01 * f02 + f11 * f12 + f21 * f22
        c0_2 = f00 * f02 + f10 * f12 + f20 * f22
        I1 = c00 + c11 + c22
        I2 = 0.5 * (I1 * I1 - (c00 * c00 + c11 * c11 + c22 * c22
                               + 2.0 * (c0_1 * c0_1 + c1_2 * c1_2 + c0_2 * c0_2)))
        I3 = det * det
        t13 = 1.0 / np.cbrt(I3)
        t23 = t13 * t13
        ab = I1 * t13 - 3.0
        bb = I2 * t23 - 3.0
        wb0 = m10 + 2.0 * m20 * ab + m11 * bb
        wb1 = m01 + m11 * ab + 2.0 * m02 * bb
        wb2 = 0.0
        if form == 1:
            wb2 = 2.0 * (det - 1.0) / d
        w1 = wb0 * t13
        w2 = wb1 * t23
        w3 = (-wb0 * I1 * t13 / (3.0 * I3) - 2.0 * wb1 * I2 * t23 / (3.0 * I3)
              + 0.5 * wb2 / det)
        # adj C = I3 C^-1
        d00 = c11 * c22 - c1_2 * c1_2
        d11 = c00 * c22 - c0_2 * c0_2
        d22 = c00 * c11 - c0_1 * c0_1
        d01 = c0_2 * c1_2 - c0_1 * c22
        d12 = c0_1 * c0_2 - c00 * c1_2
        d02 = c0_1 * c1_2 - c11 * c0_2
        dg = w1 + w2 * I1
        s00 = 2.0 * (dg - w2 * c00 + w3 * d00)
        s11 = 2.0 * (dg - w2 * c11 + w3 * d11)
        s22 = 2.0 * (dg - w2 * c22 + w3 * d22)
        s01 = 2.0 * (-w2 * c0_1 + w3 * d01)
        s12 = 2.0 * (-w2 * c1_2 + w3 * d12)
        s02 = 2.0 * (-w2 * c0_2 + w3 * d02)
        # P = F S, times the Gauss weight
        p00 = wg * (f00 * s00 + f01 * s01 + f02 * s02)
        p01 = wg * (f00 * s01 + f01 * s11 + f02 * s12)
        p02 = wg * (f00 * s02 + f01 * s12 + f02 * s22)
        p10 = wg * (f10 * s00 + f11 * s01 + f12 * s02)
        p11 = wg * (f10 * s01 + f11 * s11 + f12 * s12)
        p12 = wg * (f10 * s02 + f11 * s12 + f12 * s22)
        p20 = wg * (f20 * s00 + f21 * s01 + f22 * s02)
        p21 = wg * (f20 * s01 + f21 * s11 + f22 * s12)
        p22 = wg * (f20 * s02 + f21 * s12 + f22 * s22)
        for a in range(8):
            g0, g1, g2 = G[a, 0], G[a, 1], G[a, 2]
            fe[3 * a] += p00 * g0 + p01 * g1 + p02 * g2
            fe[3 * a + 1] += p10 * g0 + p11 * g1 + p12 * g2
            fe[3 * a + 2] += p20 * g0 + p21 * g1 + p22 * g2
            if form == 0:
                dv[3 * a] += wg * (g0 * a00 + g1 * a10 + g2 * a20)
                dv[3 * a + 1] += wg * (g0 * a01 + g1 * a11 + g2 * a21)
                dv[3 * a + 2] += wg * (g0 * a02 + g1 * a12 + g2 * a22)
        v += wg * det
        V += wg
    if form == 0:
        dU = 2.0 * (v / V - 1.0) / d
        for c in range(24):
            fe[c] += dU * dv[c]
    return jmin


@njit(cache=True, fastmath=_FM)
def brick_forces_r(q, Ve, le, w, dndX, wgp, params, sparams, s, form, ue_n, bd, dxn, wn,
                   dvn, D0, kvol, fr):
    """Fills fr (r,) with the cubature's reduced force at u_e = V_e q + le_e (q (r,), Ve
    (k, 24, r), le (k, 24) the lifting: the prescribed displacements), w (k,),
    dndX (k, 8, 8, 3), wgp (k, 8), params (k, 6) of the tissue (form 0: mean dilatation,
    1: full), sparams (k, 6) the unit stiffening (c10, c20 used), s (k,) factors - 1.
    With bd != 0, adds the damping force bd V_e^T K_n,e (V_e q - ue_n) of the bricks
    (ue_n (k, 24) = V_e q_n + le_n; K_n on the shape of damping_geometry: dxn, wn, dvn; D0
    (k, 6, 6), kvol (k,): see solver.rom.damping_kernels). Returns the smallest det F (<= 0 or NaN: an inverted brick; fr is then
    partial)."""
    k, _, r = Ve.shape
    fr[:] = 0.0
    ue = np.empty(24)
    due = np.empty(24)
    fe = np.empty(24)
    dv = np.empty(24)
    eps = np.empty(6)
    sg = np.empty(6)
    damp = bd != 0.0
    jmin = np.inf
    for e in range(k):
        for c in range(24):
            acc = 0.0
            for j in range(r):
                acc += Ve[e, c, j] * q[j]
            acc += le[e, c]
            ue[c] = acc
            due[c] = acc - ue_n[e, c]
        pe = params[e]
        se = s[e] if s[e] > 0.0 else 0.0
        m10 = pe[0] + se * sparams[e, 0]
        m01 = pe[1] + se * sparams[e, 1]
        m20 = pe[2] + se * sparams[e, 2]
        m11 = pe[3] + se * sparams[e, 3]
        m02 = pe[4] + se * sparams[e, 4]
        d = pe[5]
        jm = _brick_force(ue, dndX[e], wgp[e], m10, m01, m20, m11, m02, d, form, fe, dv)
        if not jm > 0.0:
            return jm
        if jm < jmin:
            jmin = jm
        if damp:
            _damping_force(e, due, dxn, wn, dvn, D0, kvol, form, bd, eps, sg, fe)
        we = w[e]
        for c in range(24):
            x = we * fe[c]
            for j in range(r):
                fr[j] += x * Ve[e, c, j]
    return jmin


@njit(cache=True, fastmath=_FM)
def brick_forces_full(u, bricks, dndX, wgp, params, sparams, s, form, out):
    """out (n, 3) += the unreduced forces of the bricks (m, 8) at u (n, 3): tissue and
    stiffening (sparams, s as brick_forces_r, per brick). Returns the smallest det F."""
    ue = np.empty(24)
    fe = np.empty(24)
    dv = np.empty(24)
    jmin = np.inf
    for e in range(bricks.shape[0]):
        for a in range(8):
            for i in range(3):
                ue[3 * a + i] = u[bricks[e, a], i]
        pe = params[e]
        se = s[e] if s[e] > 0.0 else 0.0
        jm = _brick_force(ue, dndX[e], wgp[e], pe[0] + se * sparams[e, 0],
                          pe[1] + se * sparams[e, 1], pe[2] + se * sparams[e, 2],
                          pe[3] + se * sparams[e, 3], pe[4] + se * sparams[e, 4], pe[5],
                          form, fe, dv)
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
def cable_forces_r(q, D, d0, AE, L0, e, need_k, add, fr, kr, tension):
    """Reduced cable forces: D (c, 3, r), d0 (c, 3), AE, L0, e (c,) active strains; fills
    (add: adds to) fr (r,), fills tension (c,) and, when need_k, kr (r, r). Returns a
    signature of the set of taut cables (a hash: equal sets, equal signatures)."""
    nc, _, r = D.shape
    if not add:
        fr[:] = 0.0
    if need_k:
        kr[:, :] = 0.0
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
            for i in range(r):
                ai = a * dn[i]
                for j in range(i, r):
                    kr[i, j] += ai * dn[j] + b * (D[c, 0, i] * D[c, 0, j]
                                                  + D[c, 1, i] * D[c, 1, j]
                                                  + D[c, 2, i] * D[c, 2, j])
    if need_k:
        for i in range(r):
            for j in range(i + 1, r):
                kr[j, i] = kr[i, j]
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
