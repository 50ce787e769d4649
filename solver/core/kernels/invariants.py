r"""The uncoupled (isochoric/volumetric) split, written once for every invariant-based law.

A law gives its energy in the isochoric invariants and J,

    W(C) = W_iso(I1b, I2b) + U(J),   I1b = I3^{-1/3} I1,  I2b = I3^{-2/3} I2,  J = I3^{1/2},

with its first and second derivatives in (I1b, I2b) and in J. This module turns them into
derivatives in the principal invariants (I1, I2, I3) of C by the chain rule,

    W_k  = sum_m Wb_m  dIb_m/dI_k
    W_kl = sum_mn Wb_mn dIb_m/dI_k dIb_n/dI_l + sum_m Wb_m d2Ib_m/dI_k dI_l,

with Ib = (I1b, I2b, J), and then into the second Piola-Kirchhoff stress and the material
tangent with the standard invariant derivatives dI1/dC = 1, dI2/dC = I1 1 - C,
dI3/dC = I3 C^-1:

    S = 2 (W_1 1 + W_2 (I1 1 - C) + W_3 I3 C^-1)
    D = 4 (sum_kl W_kl A_k (x) A_l + W_2 (1 (x) 1 - II) + W_3 I3 (C^-1 (x) C^-1 - C^-1 (.) C^-1))

where A_k = dI_k/dC, II the symmetric fourth-order identity and
(C^-1 (.) C^-1)_IJKL = (Cinv_IK Cinv_JL + Cinv_IL Cinv_JK) / 2.

Voigt order: 11, 22, 33, 12, 23, 13; D is the 6x6 matrix of D_IJKL (no factors of 2).
"""

import numpy as np
from numba import njit

VOIGT = np.array([[0, 0], [1, 1], [2, 2], [0, 1], [1, 2], [0, 2]], dtype=np.int64)


@njit(cache=True)
def deformation_gradient(ue, G, F):
    """F (3, 3) = I + sum_a u_a (x) dN_a/dX at a Gauss point; ue (8, 3), G (8, 3) dN/dX."""
    for i in range(3):
        for K in range(3):
            s = 1.0 if i == K else 0.0
            for a in range(8):
                s += ue[a, i] * G[a, K]
            F[i, K] = s


@njit(cache=True, inline="always")
def gradient_adjugate(ue, G):
    """F = I + sum_a u_a (x) dN_a/dX at a Gauss point in scalars, with adj F = det F F^-1:
    ue (24,) node-major x, y, z, G (8, 3) dN/dX. Returns F, adj F (each row-major, 9
    values) and det F as one flat 19-tuple. Inlined into its callers at numba's level, so
    that their fast-math flags apply and no small arrays are made."""
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
    return (f00, f01, f02, f10, f11, f12, f20, f21, f22,
            a00, a01, a02, a10, a11, a12, a20, a21, a22, det)


@njit(cache=True)
def inverse3(a, out):
    """out = a^-1 for a 3x3 matrix; returns det a."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) * inv
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) * inv
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) * inv
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) * inv
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) * inv
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) * inv
    return det


@njit(cache=True)
def principal_derivatives(I1, I2, I3, wb, wbb, w, ww, g):
    """Chain rule from (I1b, I2b, J) derivatives to (I1, I2, I3) derivatives.

    wb (3,), wbb (3, 3): first and second derivatives of W in (I1b, I2b, J).
    Fills w (3,) and ww (3, 3) with derivatives in (I1, I2, I3); g (3, 3) is scratch.
    """
    t13 = I3 ** (-1.0 / 3.0)
    t23 = t13 * t13
    # d Ib_m / d I_k: rows m, columns k
    g[:, :] = 0.0
    g[0, 0] = t13
    g[0, 2] = -I1 * t13 / (3.0 * I3)
    g[1, 1] = t23
    g[1, 2] = -2.0 * I2 * t23 / (3.0 * I3)
    g[2, 2] = 0.5 / np.sqrt(I3)
    # nonzero second derivatives d2 Ib_m / dI_k dI_l
    h0_02 = -t13 / (3.0 * I3)
    h0_22 = 4.0 * I1 * t13 / (9.0 * I3 * I3)
    h1_12 = -2.0 * t23 / (3.0 * I3)
    h1_22 = 10.0 * I2 * t23 / (9.0 * I3 * I3)
    h2_22 = -0.25 / (I3 * np.sqrt(I3))
    for k in range(3):
        s = 0.0
        for m in range(3):
            s += wb[m] * g[m, k]
        w[k] = s
    for k in range(3):
        for l in range(3):
            s = 0.0
            for m in range(3):
                for n in range(3):
                    s += wbb[m, n] * g[m, k] * g[n, l]
            ww[k, l] = s
    ww[0, 2] += wb[0] * h0_02
    ww[2, 0] += wb[0] * h0_02
    ww[1, 2] += wb[1] * h1_12
    ww[2, 1] += wb[1] * h1_12
    ww[2, 2] += wb[0] * h0_22 + wb[1] * h1_22 + wb[2] * h2_22


@njit(cache=True)
def stress_tangent(C, w, ww, need_d, S, D, Ci, A):
    """S (3, 3) and, when need_d, D (6, 6) from the invariant derivatives w (3,),
    ww (3, 3) at C (3, 3); Ci (3, 3) and A (3, 3, 3) are scratch."""
    I3 = inverse3(C, Ci)
    I1 = C[0, 0] + C[1, 1] + C[2, 2]
    for i in range(3):
        for j in range(3):
            d = 1.0 if i == j else 0.0
            A[0, i, j] = d
            A[1, i, j] = I1 * d - C[i, j]
            A[2, i, j] = I3 * Ci[i, j]
            S[i, j] = 2.0 * (w[0] * A[0, i, j] + w[1] * A[1, i, j] + w[2] * A[2, i, j])
    if not need_d:
        return
    for p in range(6):
        i, j = VOIGT[p, 0], VOIGT[p, 1]
        for q in range(p, 6):
            k, l = VOIGT[q, 0], VOIGT[q, 1]
            s = 0.0
            for a in range(3):
                for b in range(3):
                    s += ww[a, b] * A[a, i, j] * A[b, k, l]
            dij = 1.0 if i == j else 0.0
            dkl = 1.0 if k == l else 0.0
            dik = 1.0 if i == k else 0.0
            djl = 1.0 if j == l else 0.0
            dil = 1.0 if i == l else 0.0
            djk = 1.0 if j == k else 0.0
            s += w[1] * (dij * dkl - 0.5 * (dik * djl + dil * djk))
            s += w[2] * I3 * (Ci[i, j] * Ci[k, l]
                              - 0.5 * (Ci[i, k] * Ci[j, l] + Ci[i, l] * Ci[j, k]))
            D[p, q] = 4.0 * s
            D[q, p] = 4.0 * s
