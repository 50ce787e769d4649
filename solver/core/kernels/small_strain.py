r"""Small-strain stiffness of hyperelastic bricks on a configuration: their tangent at zero
strain, as the damping term's K_n (solver.core.terms.inertia) needs it at every substep.

At F = I an uncoupled law has S = 0 (no geometric stiffness) and the isotropic tangent
of its initial shear and bulk moduli, mu = 2 (c10 + c01) and kappa = U''(1) = 2 / d (the
c20, c11, c02 terms enter with (I1b - 3) or (I2b - 3), zero there, and so do their
derivatives: dI1b/dC = dI2b/dC = 0 at C = I). With the spatial gradients g_a = dN_a/dx
at Gauss point q (weight w_q = det J_q), node pair (a, b), components (i, j):

    deviatoric   K_aibj += w_q mu (delta_ij g_a . g_b + g_aj g_bi - 2/3 g_ai g_bj)
    volumetric   full:             K_aibj += w_q kappa g_ai g_bj
                 mean dilatation:  K_aibj += kappa / V dv_ai dv_bj,  dv_ai = sum_q w_q g_ai,
                                   V = sum_q w_q

the same matrix as solver.core.kernels.brick's tangent at u = 0 on that configuration (tested
against it), at about a fifth of its cost: no material point, no B products.

Shapes: dndx (m, 8 gp, 8, 3), w (m, 8 gp), mu and kappa (m,); ke (m, 24, 24) with DOF
order (node a, component i) -> 3 a + i.
"""

import numpy as np
from numba import njit, prange


@njit(cache=True)
def _element(G, w, mu, kappa, form, ke):
    ke[:, :] = 0.0
    dv = np.zeros(24)
    V = 0.0
    c = -2.0 / 3.0 * mu + (kappa if form == 1 else 0.0)
    for q in range(8):
        wq = w[q]
        g = G[q]
        V += wq
        for a in range(8):
            for b in range(a, 8):
                dot = wq * mu * (g[a, 0] * g[b, 0] + g[a, 1] * g[b, 1] + g[a, 2] * g[b, 2])
                for i in range(3):
                    for j in range(3):
                        s = wq * (mu * g[a, j] * g[b, i] + c * g[a, i] * g[b, j])
                        if i == j:
                            s += dot
                        ke[3 * a + i, 3 * b + j] += s
        if form == 0:
            for a in range(8):
                for i in range(3):
                    dv[3 * a + i] += wq * g[a, i]
    if form == 0:
        f = kappa / V
        for c1 in range(24):
            for c2 in range(3 * (c1 // 3), 24):
                ke[c1, c2] += f * dv[c1] * dv[c2]
    for a in range(8):                              # the lower blocks from the upper ones
        for b in range(a + 1, 8):
            for i in range(3):
                for j in range(3):
                    ke[3 * b + j, 3 * a + i] = ke[3 * a + i, 3 * b + j]


@njit(cache=True, parallel=True)
def small_strain_stiffness(dndx, w, mu, kappa, form, ke):
    """Fills ke (m, 24, 24) with each brick's stiffness at zero strain (module docstring);
    form: 0 mean dilatation, 1 full (solver.core.kernels.brick.FORMULATIONS)."""
    for e in prange(dndx.shape[0]):
        _element(dndx[e], w[e], mu[e], kappa[e], form, ke[e])
