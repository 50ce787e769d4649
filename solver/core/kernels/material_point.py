"""Energy, stress and tangent of the Mooney-Rivlin law at one material point.

point_response_ws takes its scratch arrays from the caller (``workspace()``, allocated
once per block of bricks by solver.core.kernels.brick) instead of seven small heap arrays at
every Gauss point, so that the residual and tangent passes allocate nothing per point
(docs/dev-notes/fast_path.md).
"""

import numpy as np
from numba import njit

from solver.core.kernels.invariants import principal_derivatives, stress_tangent
from solver.core.kernels.mooney_rivlin import iso_energy, vol_energy


@njit(cache=True)
def workspace():
    """Scratch of point_response_ws: (wb (3,), wbb (3, 3), w (3,), ww (3, 3), g (3, 3),
    Ci (3, 3), A (3, 3, 3))."""
    return (np.empty(3), np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty((3, 3)),
            np.empty((3, 3)), np.empty((3, 3, 3)))


@njit(cache=True)
def point_response(C, p, with_vol, need_d, S, D):
    """W at C (3, 3); fills S (3, 3) and, when need_d, D (6, 6). with_vol adds U(J) to
    the isochoric part."""
    return point_response_ws(C, p, with_vol, need_d, S, D, workspace())


@njit(cache=True)
def point_response_ws(C, p, with_vol, need_d, S, D, ws):
    """point_response with the scratch ws of workspace()."""
    wb, wbb, w, ww, g, Ci, A = ws
    I1 = C[0, 0] + C[1, 1] + C[2, 2]
    I2 = 0.5 * (I1 * I1 - (C[0, 0] ** 2 + C[1, 1] ** 2 + C[2, 2] ** 2
                           + 2.0 * (C[0, 1] ** 2 + C[1, 2] ** 2 + C[0, 2] ** 2)))
    I3 = (C[0, 0] * (C[1, 1] * C[2, 2] - C[1, 2] * C[2, 1])
          - C[0, 1] * (C[1, 0] * C[2, 2] - C[1, 2] * C[2, 0])
          + C[0, 2] * (C[1, 0] * C[2, 1] - C[1, 1] * C[2, 0]))
    t13 = I3 ** (-1.0 / 3.0)
    wb[:] = 0.0
    wbb[:, :] = 0.0
    W = iso_energy(I1 * t13, I2 * t13 * t13, p, wb, wbb)
    if with_vol:
        U, dU, ddU = vol_energy(np.sqrt(I3), p)
        W += U
        wb[2] = dU
        wbb[2, 2] = ddU
    principal_derivatives(I1, I2, I3, wb, wbb, w, ww, g)
    stress_tangent(C, w, ww, need_d, S, D, Ci, A)
    return W


def response(F, p, with_vol=True):
    """W, P = F S (3, 3), S (3, 3), D (6, 6) at a deformation gradient F (3, 3)."""
    F = np.asarray(F, dtype=np.float64)
    S = np.empty((3, 3))
    D = np.empty((6, 6))
    W = point_response(F.T @ F, np.asarray(p, dtype=np.float64), with_vol, True, S, D)
    return W, F @ S, S, D
