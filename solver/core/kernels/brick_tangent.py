r"""Internal force and consistent tangent of the hyperelastic bricks: the assembly's pass.

The same element as solver.core.kernels.brick (its reference implementation, tested against
it to rounding), with the tangent contracted node pair by node pair instead of through
the (6, 24) B matrix. With E = (F^T F - I) / 2, dE_IJ / du_ai = sym(F_iI dN_a/dX_J) and
D_IJKL the material tangent (minor symmetries), the material and geometric parts at a
Gauss point of weight w are

    K_aibj = w sum_JL dN_a/dX_J A_iJjL dN_b/dX_L,
    A_iJjL = sum_IK F_iI D_IJKL F_jK + delta_ij S_JL,

a (3, 3, 3, 3) tensor made once per point (2 x 243 multiply-adds), then H_aijL = sum_J
dN_a/dX_J A_iJjL (648) and the upper node blocks K_aibj = sum_L H_aijL dN_b/dX_L (972):
about 1,900 against about 3,200 through B (D B, then B^T (D B) on the upper triangle).

Mean dilatation (the Q1/P0 element of solver.core.kernels.brick): its volumetric tangent

    K_vol = U''(theta) / V dv (x) dv + U'(theta) d2v/dx2,
    d2v/dx_ai dx_bj = sum_g w_g J_g (dN_a/dx_i dN_b/dx_j - dN_a/dx_j dN_b/dx_i),

with dN_a/dx_i = sum_J dN_a/dX_J F^-1_Ji, is in the same form as the geometric part,
A_iJjL += U'(theta) J (F^-1_Ji F^-1_Lj - F^-1_Jj F^-1_Li), once U'(theta) is known: so
the Gauss points are walked twice, first for F, F^-1, J and theta = v / V, then for the
law and the contractions.

Shapes: u (n, 3), bricks (m, 8), dndX (m, 8, 8, 3), wgp (m, 8), params (m, 6);
fe (m, 24), ke (m, 24, 24), energy (m,), jmin (m,).
"""

import numpy as np
from numba import njit, prange

from solver.core.kernels.invariants import deformation_gradient, inverse3
from solver.core.kernels.material_point import point_response_ws
from solver.core.kernels.material_point import workspace as material_workspace
from solver.core.kernels.mooney_rivlin import vol_energy

# Voigt index of the symmetric pair (I, J): 11, 22, 33, 12, 23, 13
VOIGT_OF = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2]], dtype=np.int64)


@njit(cache=True)
def _element_tangent(ue, dndX, wgp, p, form, fe, ke, mws, Fs, Fis, Js):
    """Energy and min det F of one brick; fills fe (24,) and ke (24, 24). mws: the
    material point's scratch; Fs, Fis (8, 3, 3) and Js (8,): scratch of the first walk."""
    C = np.empty((3, 3))
    S = np.empty((3, 3))
    D = np.empty((6, 6))
    T = np.empty((3, 3, 3, 3))
    A = np.empty((3, 3, 3, 3))
    H = np.empty((8, 3, 3, 3))
    P = np.empty((3, 3))
    dv = np.zeros(24)
    jmin = np.inf
    v = 0.0
    V = 0.0
    for g in range(8):                      # first walk: F, F^-1, J, the volume
        G = dndX[g]
        F = Fs[g]
        deformation_gradient(ue, G, F)
        J = inverse3(F, Fis[g])
        Js[g] = J
        jmin = min(jmin, J)
        if J <= 0.0:
            return np.inf, J
        V += wgp[g]
        v += wgp[g] * J
    energy = 0.0
    dU = 0.0
    ddU = 0.0
    if form == 0:
        U, dU, ddU = vol_energy(v / V, p)
        energy = V * U
    for c1 in range(24):
        fe[c1] = 0.0
        for c2 in range(24):
            ke[c1, c2] = 0.0
    for g in range(8):                      # second walk: the law and the contractions
        w = wgp[g]
        G = dndX[g]
        F = Fs[g]
        Fi = Fis[g]
        J = Js[g]
        for I in range(3):
            for K in range(3):
                C[I, K] = F[0, I] * F[0, K] + F[1, I] * F[1, K] + F[2, I] * F[2, K]
        energy += w * point_response_ws(C, p, form == 1, True, S, D, mws)
        # force: w (F S) plus, with mean dilatation, U'(theta) w J F^-T; contracted with G
        wj = w * J * dU
        for i in range(3):
            for K in range(3):
                P[i, K] = w * (F[i, 0] * S[0, K] + F[i, 1] * S[1, K] + F[i, 2] * S[2, K]) \
                    + wj * Fi[K, i]
        for a in range(8):
            for i in range(3):
                fe[3 * a + i] += P[i, 0] * G[a, 0] + P[i, 1] * G[a, 1] + P[i, 2] * G[a, 2]
        if form == 0:
            for a in range(8):
                for j in range(3):
                    dv[3 * a + j] += w * J * (G[a, 0] * Fi[0, j] + G[a, 1] * Fi[1, j]
                                              + G[a, 2] * Fi[2, j])
        # T_iJKL = sum_I F_iI D_IJKL
        for i in range(3):
            for J_ in range(3):
                for K in range(3):
                    for L in range(3):
                        q = VOIGT_OF[K, L]
                        T[i, J_, K, L] = (F[i, 0] * D[VOIGT_OF[0, J_], q]
                                          + F[i, 1] * D[VOIGT_OF[1, J_], q]
                                          + F[i, 2] * D[VOIGT_OF[2, J_], q])
        # A_iJjL = w (sum_K T_iJKL F_jK + delta_ij S_JL) (+ the mean dilatation's part)
        for i in range(3):
            for J_ in range(3):
                for j in range(3):
                    for L in range(3):
                        s = T[i, J_, 0, L] * F[j, 0] + T[i, J_, 1, L] * F[j, 1] \
                            + T[i, J_, 2, L] * F[j, 2]
                        if i == j:
                            s += S[J_, L]
                        s *= w
                        if form == 0:
                            s += wj * (Fi[J_, i] * Fi[L, j] - Fi[J_, j] * Fi[L, i])
                        A[i, J_, j, L] = s
        for a in range(8):
            for i in range(3):
                for j in range(3):
                    for L in range(3):
                        H[a, i, j, L] = (G[a, 0] * A[i, 0, j, L] + G[a, 1] * A[i, 1, j, L]
                                         + G[a, 2] * A[i, 2, j, L])
        for a in range(8):
            for b in range(a, 8):
                for i in range(3):
                    for j in range(3):
                        ke[3 * a + i, 3 * b + j] += (H[a, i, j, 0] * G[b, 0]
                                                     + H[a, i, j, 1] * G[b, 1]
                                                     + H[a, i, j, 2] * G[b, 2])
    if form == 0:
        f = ddU / V
        for c1 in range(24):
            for c2 in range(3 * (c1 // 3), 24):
                ke[c1, c2] += f * dv[c1] * dv[c2]
    for a in range(8):                      # the lower node blocks from the upper ones
        for b in range(a + 1, 8):
            for i in range(3):
                for j in range(3):
                    ke[3 * b + j, 3 * a + i] = ke[3 * a + i, 3 * b + j]
    return energy, jmin


CHUNK = 32


@njit(cache=True, parallel=True)
def brick_tangent(u, bricks, dndX, wgp, params, form, fe, ke, energy, jmin):
    """All bricks in parallel (blocks of CHUNK, one scratch each); each brick writes its
    own rows, so there are no races."""
    m = bricks.shape[0]
    for c in prange((m + CHUNK - 1) // CHUNK):
        ws = material_workspace()
        ue = np.empty((8, 3))
        Fs = np.empty((8, 3, 3))
        Fis = np.empty((8, 3, 3))
        Js = np.empty(8)
        for e in range(c * CHUNK, min(m, (c + 1) * CHUNK)):
            for a in range(8):
                for i in range(3):
                    ue[a, i] = u[bricks[e, a], i]
            energy[e], jmin[e] = _element_tangent(ue, dndX[e], wgp[e], params[e], form,
                                                  fe[e], ke[e], ws, Fs, Fis, Js)
