"""Brick geometry at the Gauss points: det J and dN/dX on a configuration.

With x_a the node positions and dN_a/dxi_k (g, a, k) at Gauss point g, the Jacobian is
J_jk = sum_a x_aj dN_a/dxi_k, and dN_a/dX_j = sum_k dN_a/dxi_k (J^-1)_kj, J^-1 = adj J /
det J. Where det J = 0 the identity stands in for J (dN/dX then meaningless, det 0).
"""

from numba import njit, prange


@njit(cache=True, parallel=True)
def brick_geometry(nodes, bricks, dndxi, det, dndx):
    """nodes (n, 3), bricks (m, 8), dndxi (8 gp, 8, 3); fills det (m, 8) and
    dndx (m, 8 gp, 8, 3)."""
    for e in prange(bricks.shape[0]):
        for g in range(8):
            j00 = j01 = j02 = j10 = j11 = j12 = j20 = j21 = j22 = 0.0
            for a in range(8):
                n = bricks[e, a]
                x0, x1, x2 = nodes[n, 0], nodes[n, 1], nodes[n, 2]
                d0, d1, d2 = dndxi[g, a, 0], dndxi[g, a, 1], dndxi[g, a, 2]
                j00 += x0 * d0
                j01 += x0 * d1
                j02 += x0 * d2
                j10 += x1 * d0
                j11 += x1 * d1
                j12 += x1 * d2
                j20 += x2 * d0
                j21 += x2 * d1
                j22 += x2 * d2
            d = j00 * (j11 * j22 - j12 * j21) - j01 * (j10 * j22 - j12 * j20) \
                + j02 * (j10 * j21 - j11 * j20)
            det[e, g] = d
            if d == 0.0:
                j00, j01, j02, j10, j11, j12, j20, j21, j22 = 1.0, 0.0, 0.0, 0.0, 1.0, \
                    0.0, 0.0, 0.0, 1.0
                d = 1.0
            r = 1.0 / d
            i00 = (j11 * j22 - j12 * j21) * r
            i01 = (j02 * j21 - j01 * j22) * r
            i02 = (j01 * j12 - j02 * j11) * r
            i10 = (j12 * j20 - j10 * j22) * r
            i11 = (j00 * j22 - j02 * j20) * r
            i12 = (j02 * j10 - j00 * j12) * r
            i20 = (j10 * j21 - j11 * j20) * r
            i21 = (j01 * j20 - j00 * j21) * r
            i22 = (j00 * j11 - j01 * j10) * r
            for a in range(8):
                d0, d1, d2 = dndxi[g, a, 0], dndxi[g, a, 1], dndxi[g, a, 2]
                dndx[e, g, a, 0] = d0 * i00 + d1 * i10 + d2 * i20
                dndx[e, g, a, 1] = d0 * i01 + d1 * i11 + d2 * i21
                dndx[e, g, a, 2] = d0 * i02 + d1 * i12 + d2 * i22
