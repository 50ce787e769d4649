r"""Internal force and consistent tangent of hyperelastic 8-node bricks (total Lagrangian).

Two formulations share one kernel:

* ``mean_dilatation`` (Q1/P0, Simo-Taylor-Pister): the isochoric energy is integrated
  with the full F at the 2x2x2 Gauss points; the volumetric energy sees one dilatation per
  element, theta = v / V (current over reference volume),

      Pi_e = sum_g W_iso(F_g) w_g + V U(theta).

  With an uncoupled law this is the three-field Hu-Washizu element with element-constant
  pressure and dilatation, condensed: the constraint count drops to one per element, so
  the brick does not lock at K/mu = 500 (nu = 0.499); it is what ANSYS SOLID185 does with
  its mixed u-P option for nearly incompressible hyperelastic materials. Because Pi_e is
  an energy, the tangent is symmetric. With v = sum_g J_g w_g,

      dv/dx_ai      = sum_g J_g dN_a/dx_i w_g
      d2v/dx_ai dx_bj = sum_g J_g (dN_a/dx_i dN_b/dx_j - dN_a/dx_j dN_b/dx_i) w_g
      f_vol = U'(theta) dv/dx,   K_vol = U''(theta)/V dv/dx (x) dv/dx + U'(theta) d2v/dx2.

* ``full``: U(J) at every Gauss point (plain fully integrated trilinear brick), which
  locks for nearly incompressible materials; kept as a reference and a fidelity knob.

The full-order solver runs two faster kernels of the same element, tested against this
one to rounding: solver.core.kernels.brick_residual (forces only) and solver.core.kernels.
brick_tangent (the tangent by node-pair contractions); this one is the reference, and the
reduced-order model's (solver.rom.kernels).

Shapes: u_e (8, 3), dN/dX (8 gp, 8, 3), w = det J0 * weight (8 gp,), params (6,);
f_e (24,), K_e (24, 24) with DOF order (node a, component i) -> 3 a + i.
"""

import numpy as np
from numba import njit, prange

from solver.core.kernels.invariants import deformation_gradient, inverse3
from solver.core.kernels.material_point import point_response_ws
from solver.core.kernels.material_point import workspace as material_workspace
from solver.core.kernels.mooney_rivlin import vol_energy

FORMULATIONS = {"mean_dilatation": 0, "full": 1}


@njit(cache=True)
def _element(ue, dndX, wgp, p, form, need_k, fe, ke):
    """Element energy and min det F; fills fe (24,) and, when need_k, ke (24, 24)."""
    return _element_ws(ue, dndX, wgp, p, form, need_k, fe, ke, material_workspace())


@njit(cache=True)
def _element_ws(ue, dndX, wgp, p, form, need_k, fe, ke, mws):
    """_element with the material point's scratch mws (solver.core.kernels.material_point).
    The element's own arrays stay local: as locals LLVM knows they do not alias fe and
    ke (the tangent's loops are slower on arrays passed in)."""
    fe[:] = 0.0
    if need_k:
        ke[:, :] = 0.0
    F = np.empty((3, 3))
    Fi = np.empty((3, 3))
    C = np.empty((3, 3))
    S = np.empty((3, 3))
    P = np.empty((3, 3))
    D = np.empty((6, 6))
    B = np.empty((6, 24))
    DB = np.empty((6, 24))
    dndx = np.empty((8, 3))
    dv = np.zeros(24)
    dJ = np.zeros((8, 8, 3, 3))     # sum_g J w dN_a/dx_i dN_b/dx_j  (only for mean dilatation)
    energy = 0.0
    v = 0.0
    V = 0.0
    jmin = np.inf
    with_vol = form == 1
    for g in range(8):
        w = wgp[g]
        G = dndX[g]
        deformation_gradient(ue, G, F)
        det = inverse3(F, Fi)
        jmin = min(jmin, det)
        if det <= 0.0:
            return np.inf, det
        for I in range(3):
            for J in range(3):
                C[I, J] = F[0, I] * F[0, J] + F[1, I] * F[1, J] + F[2, I] * F[2, J]
        energy += w * point_response_ws(C, p, with_vol, need_k, S, D, mws)
        V += w
        v += w * det
        # f_ai += w (F S)_iJ dN_a/dX_J  (= B^T S in Voigt form, without building B)
        for i in range(3):
            for J in range(3):
                P[i, J] = F[i, 0] * S[0, J] + F[i, 1] * S[1, J] + F[i, 2] * S[2, J]
        for a in range(8):
            for i in range(3):
                fe[3 * a + i] += w * (P[i, 0] * G[a, 0] + P[i, 1] * G[a, 1]
                                      + P[i, 2] * G[a, 2])
        if form == 0:
            for a in range(8):
                for j in range(3):
                    dndx[a, j] = G[a, 0] * Fi[0, j] + G[a, 1] * Fi[1, j] + G[a, 2] * Fi[2, j]
                    dv[3 * a + j] += w * det * dndx[a, j]
        if not need_k:
            continue
        # B (6, 24) with engineering shear rows
        for a in range(8):
            for i in range(3):
                c = 3 * a + i
                B[0, c] = F[i, 0] * G[a, 0]
                B[1, c] = F[i, 1] * G[a, 1]
                B[2, c] = F[i, 2] * G[a, 2]
                B[3, c] = F[i, 0] * G[a, 1] + F[i, 1] * G[a, 0]
                B[4, c] = F[i, 1] * G[a, 2] + F[i, 2] * G[a, 1]
                B[5, c] = F[i, 0] * G[a, 2] + F[i, 2] * G[a, 0]
        for r in range(6):
            for c in range(24):
                s = 0.0
                for q in range(6):
                    s += D[r, q] * B[q, c]
                DB[r, c] = s * w
        for c1 in range(24):
            for c2 in range(c1, 24):
                s = 0.0
                for r in range(6):
                    s += B[r, c1] * DB[r, c2]
                ke[c1, c2] += s
        for a in range(8):
            for b in range(a, 8):
                s = 0.0
                for I in range(3):
                    for J in range(3):
                        s += G[a, I] * S[I, J] * G[b, J]
                s *= w
                for i in range(3):
                    ke[3 * a + i, 3 * b + i] += s
        if form == 0:
            wd = w * det
            for a in range(8):
                for b in range(8):
                    for i in range(3):
                        for j in range(3):
                            dJ[a, b, i, j] += wd * dndx[a, i] * dndx[b, j]
    if form == 0:
        U, dU, ddU = vol_energy(v / V, p)
        energy += V * U
        for c in range(24):
            fe[c] += dU * dv[c]
        if need_k:
            for a in range(8):
                for b in range(a, 8):
                    for i in range(3):
                        for j in range(3):
                            c1 = 3 * a + i
                            c2 = 3 * b + j
                            if c2 < c1:
                                continue
                            ke[c1, c2] += (ddU / V * dv[c1] * dv[c2]
                                           + dU * (dJ[a, b, i, j] - dJ[a, b, j, i]))
    if need_k:
        for c1 in range(24):
            for c2 in range(c1 + 1, 24):
                ke[c2, c1] = ke[c1, c2]
    return energy, jmin


CHUNK = 32      # bricks per parallel task (one scratch allocation each)


@njit(cache=True, parallel=True)
def brick_forces(u, bricks, dndX, wgp, params, form, need_k, fe, ke, energy, jmin):
    """All bricks in parallel, in blocks of CHUNK that each allocate the material point's
    scratch once; each brick writes its own rows, so there are no races.

    u (n, 3), bricks (m, 8), dndX (m, 8, 8, 3), wgp (m, 8), params (m, 6);
    fills fe (m, 24), ke (m, 24, 24) (when need_k), energy (m,), jmin (m,).
    """
    m = bricks.shape[0]
    for c in prange((m + CHUNK - 1) // CHUNK):
        ws = material_workspace()
        ue = np.empty((8, 3))
        for e in range(c * CHUNK, min(m, (c + 1) * CHUNK)):
            for a in range(8):
                for i in range(3):
                    ue[a, i] = u[bricks[e, a], i]
            energy[e], jmin[e] = _element_ws(ue, dndX[e], wgp[e], params[e], form, need_k,
                                             fe[e], ke[e], ws)


def element_response(ue, dndX, wgp, p, formulation="mean_dilatation", need_k=True):
    """One brick, for tests: (energy, f (24,), K (24, 24), min det F)."""
    fe = np.zeros(24)
    ke = np.zeros((24, 24))
    e, jm = _element(np.asarray(ue, float), np.asarray(dndX, float), np.asarray(wgp, float),
                     np.asarray(p, float), FORMULATIONS[formulation], need_k, fe, ke)
    return e, fe, ke, jm
