r"""The reduced bulk term: the tissue's volumetric energy on a few modes of the bricks'
dilatations (gappy POD).

Why. The tissue is nearly incompressible (K / mu = 500). A POD basis of displacements
holds the training states, but not their volumetric strains: a held-out state's nearest
combination of modes changes the volume of many bricks a little, and the bulk modulus
makes that dear, so the Galerkin solution trades lip position for volume (locking in the
reduced space; docs/dev-notes/realtime-balanced.md). Keeping the volumetric energy on a
few modes of the dilatation field instead of on every brick lifts that constraint, as
mean dilatation does within one brick.

The energy. With mean dilatation (solver.core.kernels.brick) brick e's volumetric energy
is V_e U(v_e / V_e), U(theta) = (theta - 1)^2 / d, so over the mesh

    Pi_vol = 1/2 |s(u)|^2,   s_e = c_e (v_e(u) - V_e),   c_e = sqrt(2 / (d_e V_e)),

v_e the current volume, V_e the reference one. P (bricks, m): the first m left singular
vectors of the training snapshots' s. The reduced term keeps the part of s on span P,
recovered from m_I sampled bricks I (QDEIM rows of P, `sample_bricks`):

    c(q) = A s_I(V q + L),   A = P_I^+ (m, m_I),   Pi_b = 1/2 |c|^2,
    f_b = J^T c,   J = dc/dq = A G_I V_I,   G_I: rows c_e dv_e/du_e (24,),
    K_b = J^T J + sum_{e in I} lam_e c_e V_e^T (d2v_e / du_e^2) V_e,   lam = A^T c,

dv/du_ai = sum_g J_g dN_a/dx_i w_g and d2v/du_ai du_bj = sum_g J_g (dN_a/dx_i dN_b/dx_j
- dN_a/dx_j dN_b/dx_i) w_g (the brick kernel's). The bricks of the force cubature then
carry the isochoric energy only (`isochoric`: d = inf). With I every brick and A = 1 the
term is the full model's volumetric energy exactly (tests/test_rom_bulk.py).

Damping: the volumetric part of beta V^T K_n V is beta J_n^T J_n, J_n from the shape at
the start of the substep (`ReducedBulk.jacobian`: the small-strain bulk stiffness on that
shape, in the reduced space).
"""

import numpy as np
import scipy.linalg as sla
from numba import njit

from solver.core.kernels.invariants import deformation_gradient, inverse3


def isochoric(params):
    """A copy of params (k, 6) with d = inf: the Mooney-Rivlin law without its volumetric
    part (U = (J - 1)^2 / d = 0), for the bricks of a model with a reduced bulk term."""
    p = np.array(params, dtype=np.float64)
    p[:, 5] = np.inf
    return p


@njit(cache=True)
def _volume(ue, dndX, wgp, need_h, dv, d2v):
    """The current volume v of a brick (float) at displacements ue (8, 3); fills dv (24,)
    and, when need_h, d2v (24, 24). Returns -1 if some det F <= 0."""
    F = np.empty((3, 3))
    Fi = np.empty((3, 3))
    dndx = np.empty((8, 3))
    dv[:] = 0.0
    if need_h:
        d2v[:, :] = 0.0
    v = 0.0
    for g in range(8):
        deformation_gradient(ue, dndX[g], F)
        det = inverse3(F, Fi)
        if not det > 0.0:
            return -1.0
        wd = wgp[g] * det
        v += wd
        G = dndX[g]
        for a in range(8):
            for j in range(3):
                dndx[a, j] = G[a, 0] * Fi[0, j] + G[a, 1] * Fi[1, j] + G[a, 2] * Fi[2, j]
                dv[3 * a + j] += wd * dndx[a, j]
        if need_h:
            for a in range(8):
                for i in range(3):
                    for b in range(8):
                        for j in range(3):
                            d2v[3 * a + i, 3 * b + j] += wd * (dndx[a, i] * dndx[b, j]
                                                               - dndx[a, j] * dndx[b, i])
    return v


@njit(cache=True)
def dilatations(u, bricks, dndX, wgp, out):
    """out (k,) = v_e(u) - V_e of every brick (u (n, 3), bricks (k, 8)); returns the
    number of inverted bricks (their entry is NaN)."""
    ue = np.empty((8, 3))
    dv = np.empty(24)
    d2v = np.empty((1, 1))
    bad = 0
    for e in range(bricks.shape[0]):
        for a in range(8):
            for i in range(3):
                ue[a, i] = u[bricks[e, a], i]
        v = _volume(ue, dndX[e], wgp[e], False, dv, d2v)
        V = 0.0
        for g in range(8):
            V += wgp[e, g]
        if v < 0.0:
            out[e] = np.nan
            bad += 1
        else:
            out[e] = v - V
    return bad


@njit(cache=True)
def _samples(q, Ve, le, dndX, wgp, ce, need_h, s, g, H):
    """At u_e = V_e q + le_e of each sampled brick: s (n,) = c_e (v_e - V_e), g (n, 24)
    = c_e dv_e/du_e and, when need_h, H (n, 24, 24) = c_e d2v_e/du_e^2. Returns False if a
    brick inverts."""
    n, _, r = Ve.shape
    ue = np.empty((8, 3))
    for e in range(n):
        for a in range(8):
            for i in range(3):
                acc = le[e, 3 * a + i]
                for j in range(r):
                    acc += Ve[e, 3 * a + i, j] * q[j]
                ue[a, i] = acc
        v = _volume(ue, dndX[e], wgp[e], need_h, g[e], H[e])
        if v < 0.0:
            return False
        V = 0.0
        for k in range(8):
            V += wgp[e, k]
        s[e] = ce[e] * (v - V)
        for c in range(24):
            g[e, c] *= ce[e]
        if need_h:
            for c in range(24):
                for d in range(24):
                    H[e, c, d] *= ce[e]
    return True


def bulk_scale(params, wgp):
    """(k,) c_e = sqrt(2 / (d_e V_e)) of bricks with law rows params (k, 6) and Gauss
    weights wgp (k, 8) (V_e = sum of wgp, mm^3; d in 1/MPa)."""
    return np.sqrt(2.0 / (np.asarray(params)[:, 5] * np.asarray(wgp).sum(axis=1)))


def bulk_modes(S, m):
    """(P (k, m), sigma): the first m left singular vectors of the dilatation snapshots S
    (k bricks, N states; the columns c * (v - V)) and all singular values."""
    P, sigma, _ = np.linalg.svd(S, full_matrices=False)
    return np.ascontiguousarray(P[:, :m]), sigma


def sample_bricks(P, extra=0):
    """(I (m + extra,), A (m, m + extra)): m bricks by QDEIM (column-pivoted QR of P^T),
    then `extra` more by the same pivoting order, and A = P_I^+ (gappy POD: c = A s_I
    recovers P^T s for s in span P)."""
    m = P.shape[1]
    _, _, piv = sla.qr(P.T, pivoting=True, mode="economic")
    I = np.sort(piv[:m + extra]) if extra else np.sort(piv[:m])
    if len(I) < m + extra:            # QR pivots number min(m, k): add by row norm
        rest = np.setdiff1d(np.argsort(-np.linalg.norm(P, axis=1)), I, assume_unique=False)
        I = np.sort(np.concatenate([I, rest[:m + extra - len(I)]]))
    return I.astype(np.int64), np.linalg.pinv(P[I])


class ReducedBulk:
    """The reduced bulk term of a reduced operator (module docstring).

    mesh: solver.core.mesh.Mesh; params (N, 6) the tissue's law per brick (all bricks);
    Vn (n, 3, r) the basis by node; samples (m_I,) brick indices; A (m, m_I)."""

    def __init__(self, mesh, params, Vn, samples, A):
        self.samples = np.asarray(samples, dtype=np.int64)
        self.A = np.ascontiguousarray(A, dtype=np.float64)
        self.conn = mesh.bricks[self.samples]
        n, r = len(self.samples), Vn.shape[2]
        self.r = r
        self.Ve = np.ascontiguousarray(Vn[self.conn].reshape(n, 24, r))
        self.dndX = np.ascontiguousarray(mesh.dn_dx[self.samples])
        self.wgp = np.ascontiguousarray(mesh.det_j[self.samples])
        self.ce = bulk_scale(np.asarray(params)[self.samples], self.wgp)
        self.s, self.g = np.zeros(n), np.zeros((n, 24))
        self.H = np.zeros((n, 24, 24))

    def lifting(self, L):
        """(m_I, 24) the sampled bricks' rows of a lifting L (n, 3)."""
        return np.ascontiguousarray(np.asarray(L)[self.conn].reshape(len(self.samples), 24))

    def _eval(self, q, le, need_h):
        if not _samples(np.ascontiguousarray(q, dtype=np.float64), self.Ve, le, self.dndX,
                        self.wgp, self.ce, need_h, self.s, self.g, self.H):
            return None
        return np.einsum("ed,edr->er", self.g, self.Ve)          # G_I V_I (m_I, r)

    def energy(self, q, le):
        """Pi_b (N mm) at q (r,), le (m_I, 24) the lifting's rows; nan if a brick inverts."""
        if self._eval(q, le, False) is None:
            return np.nan
        c = self.A @ self.s
        return 0.5 * float(c @ c)

    def forces(self, q, le, need_k):
        """(f_b (r,), K_b (r, r) or None); (None, None) if a sampled brick inverts."""
        GV = self._eval(q, le, need_k)
        if GV is None:
            return None, None
        J = self.A @ GV
        c = self.A @ self.s
        f = J.T @ c
        if not need_k:
            return f, None
        lam = self.A.T @ c
        K = J.T @ J
        HV = np.einsum("ecd,edr->ecr", self.H, self.Ve)
        K += np.einsum("ecr,ecs,e->rs", self.Ve, HV, lam)
        return f, 0.5 * (K + K.T)

    def jacobian(self, q, le, dle=None):
        """J_n (m, r) of the damping on the shape at q: A G_I V_I with each row of G_I
        scaled by sqrt(V_e / v_e), so that J_n^T J_n is the small-strain bulk stiffness
        (2 / d) / v_e dv dv^T on that shape (solver.rom.damping_kernels, the full model's
        K_n), reduced; J_n = J at rest. With dle (m_I, 24), also the same rows times dle
        (m,) (a second return). None if a sampled brick inverts."""
        GV = self._eval(q, le, False)
        if GV is None:
            return None if dle is None else (None, None)
        V0 = self.wgp.sum(axis=1)
        k = np.sqrt(V0 / (self.s / self.ce + V0))
        J = self.A @ (k[:, None] * GV)
        if dle is None:
            return J
        return J, self.A @ (k * np.einsum("ed,ed->e", self.g, dle))
