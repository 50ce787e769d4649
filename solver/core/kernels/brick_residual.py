r"""Internal force of the hyperelastic bricks without the tangent: the residual's pass.

The same forces and energy as solver.core.kernels.brick (tested against it to rounding),
from the second Piola-Kirchhoff stress in the principal invariants (I1, I2, I3) of
C = F^T F (solver.core.kernels.invariants' chain rule, first derivatives only): with the
isochoric invariants I1b = I3^(-1/3) I1, I2b = I3^(-2/3) I2 and the law's derivatives
Wb1 = dW/dI1b, Wb2 = dW/dI2b,

    W_1 = Wb1 I3^(-1/3),   W_2 = Wb2 I3^(-2/3),
    W_3 = -(Wb1 I1b + 2 Wb2 I2b) / (3 I3) (+ U'(J) / (2 J) for ``full``),
    S = 2 (W_1 1 + W_2 (I1 1 - C) + W_3 adj C),   adj C = I3 C^-1,
    P = F S,   f_ai = sum_g w_g P_g,iJ dN_a/dX_J (g)  (no B matrix).

With mean dilatation the volumetric part is U'(theta) dv/dx after the Gauss loop,
theta = v / V, dv/dx_ai = sum_g w_g (dN_a/dX adj F)_i. Everything per Gauss point is
written in scalars (no small arrays; F and adj F from
solver.core.kernels.invariants.gradient_adjugate). The reduced model's online kernels
(solver.rom.online_kernels) call the same element function; it is inlined into each
caller at numba's level (inline="always"), so that their fast-math flags apply to it (a
call across numba modules is not inlined by LLVM).

Shapes as solver.core.kernels.brick: u (n, 3), bricks (m, 8), dndX (m, 8, 8, 3), wgp (m, 8),
params (m, 6); fe (m, 24), energy (m,), jmin (m,).
"""

import numpy as np
from numba import njit, prange

from solver.core.kernels.invariants import gradient_adjugate
from solver.core.kernels.mooney_rivlin import vol_energy


@njit(cache=True, inline="always")
def element_residual(ue, dndX, wgp, p, form, fe, dv):
    """(energy, smallest det F) of one brick at its displacements ue (24,: node-major
    x, y, z) for the law's row p (6,) (form 0: mean dilatation, 1: full); fills fe (24,)
    with its internal force; dv (24,) is scratch. A det F <= 0 or NaN returns
    (inf, det F) at once, fe partial."""
    for c in range(24):
        fe[c] = 0.0
        dv[c] = 0.0
    c10, c01, c20, c11, c02 = p[0], p[1], p[2], p[3], p[4]
    energy = 0.0
    jmin = np.inf
    v = 0.0
    V = 0.0
    for g in range(8):
        G = dndX[g]
        wg = wgp[g]
        f00, f01, f02, f10, f11, f12, f20, f21, f22, a00, a01, a02, a10, a11, a12, a20, \
            a21, a22, det = gradient_adjugate(ue, G)
        if not det > 0.0:
            return np.inf, det                     # <= 0 or NaN
        if det < jmin:
            jmin = det
        # C = F^T F (symmetric)
        c00 = f00 * f00 + f10 * f10 + f20 * f20
        cc11 = f01 * f01 + f11 * f11 + f21 * f21
        c22 = f02 * f02 + f12 * f12 + f22 * f22
        c0_1 = f00 * f01 + f10 * f11 + f20 * f21
        c1_2 = f01 * f02 + f11 * f12 + f21 * f22
        c0_2 = f00 * f02 + f10 * f12 + f20 * f22
        I1 = c00 + cc11 + c22
        I2 = 0.5 * (I1 * I1 - (c00 * c00 + cc11 * cc11 + c22 * c22
                               + 2.0 * (c0_1 * c0_1 + c1_2 * c1_2 + c0_2 * c0_2)))
        I3 = det * det
        t13 = 1.0 / np.cbrt(I3)                    # I3^(-1/3) = J^(-2/3)
        t23 = t13 * t13
        ab = I1 * t13 - 3.0
        bb = I2 * t23 - 3.0
        energy += wg * (c10 * ab + c01 * bb + c20 * ab * ab + c11 * ab * bb + c02 * bb * bb)
        wb0 = c10 + 2.0 * c20 * ab + c11 * bb
        wb1 = c01 + c11 * ab + 2.0 * c02 * bb
        w3 = (-wb0 * I1 * t13 - 2.0 * wb1 * I2 * t23) / (3.0 * I3)
        if form == 1:
            U, dU, _ = vol_energy(det, p)
            energy += wg * U
            w3 += 0.5 * dU / det
        w1 = wb0 * t13
        w2 = wb1 * t23
        # adj C = I3 C^-1
        d00 = cc11 * c22 - c1_2 * c1_2
        d11 = c00 * c22 - c0_2 * c0_2
        d22 = c00 * cc11 - c0_1 * c0_1
        d01 = c0_2 * c1_2 - c0_1 * c22
        d12 = c0_1 * c0_2 - c00 * c1_2
        d02 = c0_1 * c1_2 - cc11 * c0_2
        dg = w1 + w2 * I1
        s00 = 2.0 * (dg - w2 * c00 + w3 * d00)
        s11 = 2.0 * (dg - w2 * cc11 + w3 * d11)
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
        U, dU, _ = vol_energy(v / V, p)
        energy += V * U
        for c in range(24):
            fe[c] += dU * dv[c]
    return energy, jmin


CHUNK = 64


@njit(cache=True, parallel=True)
def brick_residual(u, bricks, dndX, wgp, params, form, fe, energy, jmin):
    """All bricks' forces in parallel (blocks of CHUNK); each brick writes its own row."""
    m = bricks.shape[0]
    for c in prange((m + CHUNK - 1) // CHUNK):
        ue = np.empty(24)
        dv = np.empty(24)
        for e in range(c * CHUNK, min(m, (c + 1) * CHUNK)):
            for a in range(8):
                for i in range(3):
                    ue[3 * a + i] = u[bricks[e, a], i]
            energy[e], jmin[e] = element_residual(ue, dndX[e], wgp[e], params[e], form,
                                                  fe[e], dv)
