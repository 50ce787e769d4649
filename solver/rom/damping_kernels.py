r"""Numba kernels of the damping's passive small-strain stiffness K_n on a shape.

K_n = sum_e int B_n^T D0 B_n dv_n on the shape X + u (solver.core.terms.inertia.passive_tangent):
with F the deformation gradient of u, dN/dx = dN/dX F^-1, dv = w det F, B_n the small-strain
B of dN/dx, D0 the law's tangent at C = 1 (per brick, solver.rom.online.small_strain_tangents)
and, for mean dilatation, + U''(1) / V dv dv^T with dv = sum_g w det F dN/dx.

* ``damping_geometry``: dN/dx, w det F and dv of the cubature's bricks on X + V q (once per
  substep; brick_forces_nodal's matrix-free damping force and passive_stiffness_kv use them);
* ``passive_stiffness_kv``: w_e K_n,e V_e per brick, whose product with V gives the
  reduced matrix sum_e w_e V_e^T K_n,e V_e on that shape (the
  damping part of the Newton tangent);
* ``passive_apply``: the full-order product K_n du, without element matrices (the trust
  check's residual, solver.rom.trust).
"""

import numpy as np
from numba import njit

from solver.core import _cache  # noqa: F401  (the solver's kernel cache, before any @njit)
from solver.core.kernels.invariants import gradient_adjugate

_FM = {"contract", "reassoc", "arcp"}          # no nnan / ninf: NaN and inf checks stay


@njit(cache=True, fastmath=_FM)
def damping_geometry(u, conn, dndX, wgp, ue, dxn, wn, dvn):
    """The shape X + u of the selected bricks for their damping (u (b, 3) the displacements
    V q + L of their nodes, conn (k, 8) the bricks' local node indices into u): fills ue
    (k, 24) the bricks' displacements, dxn (k, 8, 8, 3) dN/dx = dN/dX adj F / det F, wn
    (k, 8) w det F and dvn (k, 24) sum_g wn dN/dx. Returns the smallest det F (a det F <= 0
    or NaN at once)."""
    k = conn.shape[0]
    jmin = np.inf
    for e in range(k):
        for a in range(8):
            n = conn[e, a]
            for i in range(3):
                ue[e, 3 * a + i] = u[n, i]
        for c in range(24):
            dvn[e, c] = 0.0
        for g in range(8):
            G = dndX[e, g]
            _, _, _, _, _, _, _, _, _, a00, a01, a02, a10, a11, a12, a20, a21, a22, det = \
                gradient_adjugate(ue[e], G)
            if not det > 0.0:
                return det
            if det < jmin:
                jmin = det
            inv = 1.0 / det
            wd = wgp[e, g] * det
            wn[e, g] = wd
            for a in range(8):
                g0, g1, g2 = G[a, 0], G[a, 1], G[a, 2]
                x0 = (g0 * a00 + g1 * a10 + g2 * a20) * inv
                x1 = (g0 * a01 + g1 * a11 + g2 * a21) * inv
                x2 = (g0 * a02 + g1 * a12 + g2 * a22) * inv
                dxn[e, g, a, 0] = x0
                dxn[e, g, a, 1] = x1
                dxn[e, g, a, 2] = x2
                dvn[e, 3 * a] += wd * x0
                dvn[e, 3 * a + 1] += wd * x1
                dvn[e, 3 * a + 2] += wd * x2
    return jmin


@njit(cache=True, fastmath=_FM)
def passive_stiffness_kv(Ve, w, dxn, wn, dvn, D0, kvol, form, kv):
    """kv (k, 24, r) = w_e K_n,e V_e per brick of the cubature, so that its passive
    small-strain stiffness on the shape of damping_geometry (dxn, wn, dvn) is the one
    product sum_e V_e^T kv_e = Ve.reshape(-1, r).T @ kv.reshape(-1, r) (a BLAS matrix
    product, solver.rom.online.OnlineOperator.damping_tangent). D0 (k, 6, 6), kvol (k,)
    (see passive_apply); K_n,e = sum_g wn B^T D0 B (+ kvol / V dv dv^T for form 0), B
    the small-strain B of dN/dx."""
    k, _, r = Ve.shape
    ke = np.empty((24, 24))
    B = np.zeros((6, 24))
    DB = np.empty((6, 24))
    for e in range(k):
        ke[:, :] = 0.0
        vol = 0.0
        for g in range(8):
            G = dxn[e, g]
            for a in range(8):
                c = 3 * a
                B[0, c] = G[a, 0]
                B[1, c + 1] = G[a, 1]
                B[2, c + 2] = G[a, 2]
                B[3, c] = G[a, 1]
                B[3, c + 1] = G[a, 0]
                B[4, c + 1] = G[a, 2]
                B[4, c + 2] = G[a, 1]
                B[5, c] = G[a, 2]
                B[5, c + 2] = G[a, 0]
            wg = wn[e, g]
            for p in range(6):
                for c in range(24):
                    acc = 0.0
                    for t in range(6):
                        acc += D0[e, p, t] * B[t, c]
                    DB[p, c] = wg * acc
            for c1 in range(24):
                for c2 in range(c1, 24):
                    acc = 0.0
                    for p in range(6):
                        acc += B[p, c1] * DB[p, c2]
                    ke[c1, c2] += acc
            vol += wg
        if form == 0:
            f = kvol[e] / vol
            for c1 in range(24):
                for c2 in range(c1, 24):
                    ke[c1, c2] += f * dvn[e, c1] * dvn[e, c2]
        for c1 in range(24):
            for c2 in range(c1 + 1, 24):
                ke[c2, c1] = ke[c1, c2]
        we = w[e]
        for c1 in range(24):
            for c2 in range(24):
                ke[c1, c2] *= we
        np.dot(ke, Ve[e], kv[e])                # BLAS


@njit(cache=True, fastmath=_FM)
def passive_apply(u, du, bricks, dndX, wgp, D0, kvol, form, out):
    """out (n, 3) += K_n du (module docstring): u, du (n, 3), bricks (m, 8), dndX (m, 8, 8,
    3), wgp (m, 8), D0 (m, 6, 6) Voigt (11, 22, 33, 12, 23, 13), kvol (m,) U''(1) (used for
    form 0). Returns the smallest det F."""
    m = bricks.shape[0]
    F = np.empty((3, 3))
    Fi = np.empty((3, 3))
    dx = np.empty((8, 3))
    due = np.empty((8, 3))
    dv = np.empty((8, 3))
    fe = np.empty((8, 3))
    eps = np.empty(6)
    sig = np.empty(6)
    jmin = np.inf
    for e in range(m):
        for a in range(8):
            for i in range(3):
                due[a, i] = du[bricks[e, a], i]
                fe[a, i] = 0.0
                dv[a, i] = 0.0
        vol = 0.0
        for g in range(8):
            G = dndX[e, g]
            for i in range(3):
                for J in range(3):
                    acc = 1.0 if i == J else 0.0
                    for a in range(8):
                        acc += u[bricks[e, a], i] * G[a, J]
                    F[i, J] = acc
            det = (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1])
                   - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
                   + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))
            if not det > 0.0:
                return det                             # <= 0 or NaN
            if det < jmin:
                jmin = det
            inv = 1.0 / det
            Fi[0, 0] = (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) * inv
            Fi[0, 1] = (F[0, 2] * F[2, 1] - F[0, 1] * F[2, 2]) * inv
            Fi[0, 2] = (F[0, 1] * F[1, 2] - F[0, 2] * F[1, 1]) * inv
            Fi[1, 0] = (F[1, 2] * F[2, 0] - F[1, 0] * F[2, 2]) * inv
            Fi[1, 1] = (F[0, 0] * F[2, 2] - F[0, 2] * F[2, 0]) * inv
            Fi[1, 2] = (F[0, 2] * F[1, 0] - F[0, 0] * F[1, 2]) * inv
            Fi[2, 0] = (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]) * inv
            Fi[2, 1] = (F[0, 1] * F[2, 0] - F[0, 0] * F[2, 1]) * inv
            Fi[2, 2] = (F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]) * inv
            wn = wgp[e, g] * det
            for a in range(8):
                for j in range(3):
                    dx[a, j] = G[a, 0] * Fi[0, j] + G[a, 1] * Fi[1, j] + G[a, 2] * Fi[2, j]
            # engineering strain of du on the current shape (B's Voigt order)
            for p in range(6):
                eps[p] = 0.0
            for a in range(8):
                eps[0] += dx[a, 0] * due[a, 0]
                eps[1] += dx[a, 1] * due[a, 1]
                eps[2] += dx[a, 2] * due[a, 2]
                eps[3] += dx[a, 1] * due[a, 0] + dx[a, 0] * due[a, 1]
                eps[4] += dx[a, 2] * due[a, 1] + dx[a, 1] * due[a, 2]
                eps[5] += dx[a, 2] * due[a, 0] + dx[a, 0] * due[a, 2]
            for p in range(6):
                acc = 0.0
                for t in range(6):
                    acc += D0[e, p, t] * eps[t]
                sig[p] = wn * acc
            for a in range(8):
                fe[a, 0] += dx[a, 0] * sig[0] + dx[a, 1] * sig[3] + dx[a, 2] * sig[5]
                fe[a, 1] += dx[a, 1] * sig[1] + dx[a, 0] * sig[3] + dx[a, 2] * sig[4]
                fe[a, 2] += dx[a, 2] * sig[2] + dx[a, 1] * sig[4] + dx[a, 0] * sig[5]
                if form == 0:
                    for j in range(3):
                        dv[a, j] += wn * dx[a, j]
            vol += wn
        if form == 0:
            acc = 0.0
            for a in range(8):
                for j in range(3):
                    acc += dv[a, j] * due[a, j]
            acc *= kvol[e] / vol
            for a in range(8):
                for j in range(3):
                    fe[a, j] += acc * dv[a, j]
        for a in range(8):
            for j in range(3):
                out[bricks[e, a], j] += fe[a, j]
    return jmin
