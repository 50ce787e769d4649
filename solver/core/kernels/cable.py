r"""Tension-only cables between embedded points.

Cable c joins points p and q, whose positions are x = X + sum_a w_a u_a over the 8
nodes of their host bricks (w = 0 for a point fixed on bone). With l = |x_q - x_p|,
n = (x_q - x_p) / l, eps = l / L0 - 1 and the active strain e (>= 0),

    Psi = L0 AE/2 (eps + e)^2,  T = AE (eps + e)        where eps + e > 0, else 0,
    dPsi/dx_q = T n = -dPsi/dx_p,
    d2Psi/dx_q dx_q = AE/L0 n (x) n + T/l (1 - n (x) n).

Shapes: X (c, 2, 3), w (c, 2, 8), nodes (c, 16) (host nodes of p then of q),
AE (c,), L0 (c,), e (c,); outputs fe (c, 48), ke (c, 48, 48), tension (c,).
"""

import numpy as np
from numba import njit


@njit(cache=True)
def cable_forces(u, X, w, nodes, AE, L0, e, need_k, fe, ke, tension):
    """Energy of all cables; fills fe, ke (when need_k), tension."""
    total = 0.0
    for c in range(X.shape[0]):
        xp = X[c, 0].copy()
        xq = X[c, 1].copy()
        for a in range(8):
            for i in range(3):
                xp[i] += w[c, 0, a] * u[nodes[c, a], i]
                xq[i] += w[c, 1, a] * u[nodes[c, 8 + a], i]
        d = xq - xp
        l = np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        n = d / l
        s = l / L0[c] - 1.0 + e[c]
        fe[c, :] = 0.0
        if need_k:
            ke[c, :, :] = 0.0
        if s <= 0.0:
            tension[c] = 0.0
            continue
        T = AE[c] * s
        tension[c] = T
        total += 0.5 * L0[c] * AE[c] * s * s
        # signed weights: -w_p on the first 8 nodes, +w_q on the last 8
        sw = np.empty(16)
        for a in range(8):
            sw[a] = -w[c, 0, a]
            sw[8 + a] = w[c, 1, a]
        for a in range(16):
            for i in range(3):
                fe[c, 3 * a + i] = sw[a] * T * n[i]
        if not need_k:
            continue
        k3 = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                k3[i, j] = (AE[c] / L0[c] - T / l) * n[i] * n[j] + (T / l if i == j else 0.0)
        for a in range(16):
            for b in range(16):
                wab = sw[a] * sw[b]
                if wab == 0.0:
                    continue
                for i in range(3):
                    for j in range(3):
                        ke[c, 3 * a + i, 3 * b + j] = wab * k3[i, j]
    return total
