r"""Internal force of the hyperelastic bricks without the tangent: the residual's pass.

The same forces and energy as solver.core.kernels.brick (tested against it to rounding), by
the first Piola-Kirchhoff stress written in F directly. With the isochoric invariants
I1b = J^(-2/3) I1, I2b = J^(-4/3) I2 and the law's derivatives Wb1 = dW/dI1b,
Wb2 = dW/dI2b (solver.core.kernels.invariants' chain rule, first derivatives only; C = F^T F,
F C^-1 = F^-T),

    P_iso = 2 (Wb1 J^(-2/3) + Wb2 J^(-4/3) I1) F - 2 Wb2 J^(-4/3) F C
            - 2/3 (Wb1 I1b + 2 Wb2 I2b) F^-T,

and the volumetric part U'(J) J F^-T at each Gauss point (``full``) or, with mean
dilatation, U'(theta) dv/dx = U'(theta) sum_g w_g J_g F_g^-T dN/dX_g, added after the
loop once theta = v / V is known. f_ai = sum_g w_g P_g,iJ dN_a/dX_J (g).

What it saves against the tangent's kernel per Gauss point: the second derivatives, the
inverse of C, a second power J^(-2/3), the B-free spatial gradients (the mean dilatation's
dv/dx is folded into the same contraction as the stress).

Shapes as solver.core.kernels.brick: u (n, 3), bricks (m, 8), dndX (m, 8, 8, 3), wgp (m, 8),
params (m, 6); fe (m, 24), energy (m,), jmin (m,).
"""

import numpy as np
from numba import njit, prange

from solver.core.kernels.invariants import deformation_gradient, inverse3
from solver.core.kernels.mooney_rivlin import vol_energy


@njit(cache=True)
def _element_residual(ue, dndX, wgp, p, form, fe, Q):
    """Energy and min det F of one brick; fills fe (24,). Q (8, 3, 3) is scratch: each
    Gauss point's w P (plus, with mean dilatation, w J F^-T until U'(theta) is known)."""
    F = np.empty((3, 3))
    Fi = np.empty((3, 3))
    M = np.empty((8, 3, 3))
    c10, c01, c20, c11, c02 = p[0], p[1], p[2], p[3], p[4]
    energy = 0.0
    v = 0.0
    V = 0.0
    jmin = np.inf
    for g in range(8):
        w = wgp[g]
        G = dndX[g]
        deformation_gradient(ue, G, F)
        J = inverse3(F, Fi)
        jmin = min(jmin, J)
        if J <= 0.0:
            return np.inf, J
        c00 = F[0, 0] ** 2 + F[1, 0] ** 2 + F[2, 0] ** 2
        c11_ = F[0, 1] ** 2 + F[1, 1] ** 2 + F[2, 1] ** 2
        c22 = F[0, 2] ** 2 + F[1, 2] ** 2 + F[2, 2] ** 2
        c01_ = F[0, 0] * F[0, 1] + F[1, 0] * F[1, 1] + F[2, 0] * F[2, 1]
        c12 = F[0, 1] * F[0, 2] + F[1, 1] * F[1, 2] + F[2, 1] * F[2, 2]
        c02_ = F[0, 0] * F[0, 2] + F[1, 0] * F[1, 2] + F[2, 0] * F[2, 2]
        I1 = c00 + c11_ + c22
        I2 = 0.5 * (I1 * I1 - (c00 * c00 + c11_ * c11_ + c22 * c22
                               + 2.0 * (c01_ * c01_ + c12 * c12 + c02_ * c02_)))
        t13 = 1.0 / np.cbrt(J * J)                    # J^(-2/3)
        t23 = t13 * t13
        a1 = I1 * t13 - 3.0
        a2 = I2 * t23 - 3.0
        wb1 = c10 + 2.0 * c20 * a1 + c11 * a2
        wb2 = c01 + c11 * a1 + 2.0 * c02 * a2
        energy += w * (c10 * a1 + c01 * a2 + c20 * a1 * a1 + c11 * a1 * a2 + c02 * a2 * a2)
        kf = 2.0 * (wb1 * t13 + wb2 * t23 * I1)
        ki = -2.0 / 3.0 * (wb1 * (a1 + 3.0) + 2.0 * wb2 * (a2 + 3.0))
        if form == 1:
            U, dU, _ = vol_energy(J, p)
            energy += w * U
            ki += dU * J
        V += w
        v += w * J
        for i in range(3):
            for K in range(3):
                Q[g, i, K] = w * (kf * F[i, K] + ki * Fi[K, i])
                M[g, i, K] = w * J * Fi[K, i]
        if wb2 != 0.0:
            kc = -2.0 * wb2 * t23 * w
            for i in range(3):
                f0, f1, f2 = F[i, 0], F[i, 1], F[i, 2]
                Q[g, i, 0] += kc * (f0 * c00 + f1 * c01_ + f2 * c02_)
                Q[g, i, 1] += kc * (f0 * c01_ + f1 * c11_ + f2 * c12)
                Q[g, i, 2] += kc * (f0 * c02_ + f1 * c12 + f2 * c22)
    dU = 0.0
    if form == 0:
        U, dU, _ = vol_energy(v / V, p)
        energy += V * U
    for c in range(24):
        fe[c] = 0.0
    for g in range(8):
        G = dndX[g]
        for i in range(3):
            q0 = Q[g, i, 0] + dU * M[g, i, 0]
            q1 = Q[g, i, 1] + dU * M[g, i, 1]
            q2 = Q[g, i, 2] + dU * M[g, i, 2]
            for a in range(8):
                fe[3 * a + i] += q0 * G[a, 0] + q1 * G[a, 1] + q2 * G[a, 2]
    return energy, jmin


CHUNK = 64


@njit(cache=True, parallel=True)
def brick_residual(u, bricks, dndX, wgp, params, form, fe, energy, jmin):
    """All bricks' forces in parallel (blocks of CHUNK); each brick writes its own row."""
    m = bricks.shape[0]
    for c in prange((m + CHUNK - 1) // CHUNK):
        ue = np.empty((8, 3))
        Q = np.empty((8, 3, 3))
        for e in range(c * CHUNK, min(m, (c + 1) * CHUNK)):
            for a in range(8):
                for i in range(3):
                    ue[a, i] = u[bricks[e, a], i]
            energy[e], jmin[e] = _element_residual(ue, dndX[e], wgp[e], params[e], form,
                                                   fe[e], Q)
