r"""Reduced element forces: the brick kernel on a few selected bricks, projected.

For the selected bricks e (the cubature of solver.rom.ecsw) with weights w_e and the
basis rows V_e (24, r) of their nodes (zero rows on constrained DOFs), at reduced
coordinates q (r,):

    u_e = V_e q,
    f_r = sum_e w_e V_e^T (f_e(u_e) + s_e f^s_e(u_e)),
    K_r = sum_e w_e V_e^T (K_e(u_e) + s_e K^s_e(u_e)) V_e,

with f_e, K_e the tissue brick (solver.core.kernels.brick, mean dilatation) and f^s_e, K^s_e
the stiffening brick of unit factor (isochoric, plain trilinear, c10 and c20 of the
tissue, as solver.face.terms.stiffening) scaled by s_e = k_e(a) - 1 >= 0. The stiffening
energy is linear in its (c10, c20), so one unit-factor evaluation times s_e is the
stiffening term's contribution exactly. Serial: a few dozen bricks do not pay for
threads. Returns the smallest det F (<= 0: an inverted brick, the state is refused).
"""

import numpy as np
from numba import njit

from solver.core.kernels.brick import _element


@njit(cache=True)
def _gather(Ve_e, q, le_e, ue):
    """ue (8, 3) = the brick's displacements V_e q + le_e (Ve_e (24, r), q (r,), le_e (24,)
    the lifting: the prescribed displacements)."""
    for a in range(8):
        for i in range(3):
            acc = le_e[3 * a + i]
            for j in range(q.shape[0]):
                acc += Ve_e[3 * a + i, j] * q[j]
            ue[a, i] = acc


@njit(cache=True)
def reduced_bricks(q, Ve, le, w, dndX, wgp, params, form, sparams, s, need_k, fr, kr):
    """q (r,), Ve (k, 24, r), le (k, 24) the lifting (u_e = V_e q + le_e), w (k,), dndX
    (k, 8, 8, 3), wgp (k, 8), params (k, 6) of the tissue (formulation form), sparams
    (k, 6) of the unit stiffening (form 'full'), s (k,) stiffening factors - 1; fills fr (r,) and, when need_k, kr (r, r). Returns
    the smallest det F over the bricks."""
    k, _, r = Ve.shape
    fr[:] = 0.0
    if need_k:
        kr[:, :] = 0.0
    ue = np.empty((8, 3))
    fe = np.empty(24)
    ke = np.empty((24, 24))
    fs = np.empty(24)
    ks = np.empty((24, 24))
    kv = np.empty((24, r))
    tmp = np.empty((r, r))
    jmin = np.inf
    for e in range(k):
        _gather(Ve[e], q, le[e], ue)
        _, jm = _element(ue, dndX[e], wgp[e], params[e], form, need_k, fe, ke)
        jmin = min(jmin, jm)
        if jm <= 0.0:
            return jmin
        if s[e] > 0.0:
            _, jm = _element(ue, dndX[e], wgp[e], sparams[e], 1, need_k, fs, ks)
            for c in range(24):
                fe[c] += s[e] * fs[c]
            if need_k:
                for c in range(24):
                    for d in range(24):
                        ke[c, d] += s[e] * ks[c, d]
        we = w[e]
        for j in range(r):
            acc = 0.0
            for c in range(24):
                acc += Ve[e, c, j] * fe[c]
            fr[j] += we * acc
        if need_k:
            _project_k(Ve[e], ke, we, kv, kr, tmp)
    if need_k:
        _symmetrize(kr)
    return jmin


@njit(cache=True)
def element_forces(u, bricks, dndX, wgp, params, form, sparams, s, out):
    """Unreduced element forces (m, 24) f_e + s_e f^s_e at u (n, 3) for training."""
    ue = np.empty((8, 3))
    fs = np.empty(24)
    dummy = np.empty((24, 24))
    for e in range(bricks.shape[0]):
        for a in range(8):
            for i in range(3):
                ue[a, i] = u[bricks[e, a], i]
        _element(ue, dndX[e], wgp[e], params[e], form, False, out[e], dummy)
        if s[e] > 0.0:
            _element(ue, dndX[e], wgp[e], sparams[e], 1, False, fs, dummy)
            for c in range(24):
                out[e, c] += s[e] * fs[c]


@njit(cache=True)
def _project_k(Vb, ke, we, kv, kr, tmp):
    """kr (r, r) += we Vb^T ke Vb (upper triangle only), Vb (24, r); kv (24, r), tmp
    (r, r) work. The two products by BLAS (np.dot in numba: ten times the loops' speed
    at r ~ 100)."""
    r = Vb.shape[1]
    np.dot(ke, Vb, kv)
    np.dot(Vb.T, kv, tmp)
    for i in range(r):
        for j in range(i, r):
            kr[i, j] += we * tmp[i, j]


@njit(cache=True)
def _symmetrize(kr):
    r = kr.shape[0]
    for i in range(r):
        for j in range(i + 1, r):
            kr[j, i] = kr[i, j]


@njit(cache=True)
def brick_tangents_split(q, Ve, le, w, dndX, wgp, params, form, sparams, slot, kt, ks):
    """The cubature's tangent at u_e = V_e q + le_e (le (k, 24)) split by activation: kt
    (r, r) = sum_e w_e V_e^T K_e V_e (tissue) and, for each brick e with slot[e] >= 0,
    ks[slot[e]] (r, r) = w_e V_e^T K^s_e V_e (its unit stiffening), so that reduced_bricks' tangent is kt + sum_e s_e ks[slot[e]]
    for any factors s. Returns the smallest det F."""
    k, _, r = Ve.shape
    kt[:, :] = 0.0
    ue = np.empty((8, 3))
    fe = np.empty(24)
    ke = np.empty((24, 24))
    kv = np.empty((24, r))
    tmp = np.empty((r, r))
    jmin = np.inf
    for e in range(k):
        _gather(Ve[e], q, le[e], ue)
        _, jm = _element(ue, dndX[e], wgp[e], params[e], form, True, fe, ke)
        jmin = min(jmin, jm)
        if jm <= 0.0:
            return jmin
        _project_k(Ve[e], ke, w[e], kv, kt, tmp)
        m = slot[e]
        if m >= 0:
            ks[m, :, :] = 0.0
            _element(ue, dndX[e], wgp[e], sparams[e], 1, True, fe, ke)
            _project_k(Ve[e], ke, w[e], kv, ks[m], tmp)
            _symmetrize(ks[m])
    _symmetrize(kt)
    return jmin
