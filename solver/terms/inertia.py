r"""Inertia and Rayleigh damping for implicit time stepping.

Mass: lumped, the row sums of the consistent brick mass matrix,
m_a = rho sum_e sum_g N_a(xi_g) det J_g w_g (positive for trilinear bricks and wedges),
so M is diagonal: cheap, and no spurious coupling through the mass.

Damping: C = alpha M + beta K0 with K0 the tangent of the passive tissue at the reference
state, assembled once. A constant, symmetric, positive semi-definite C dissipates energy
at every state (P = v^T C v >= 0), costs no assembly per iteration and keeps the tangent
symmetric. The current tangent would follow stiffening and large strains, but it can
lose definiteness (and with it the guarantee of dissipation) and must be rebuilt each
iteration; with alpha = 40 1/s, beta = 0.03 s every mode is overdamped anyway.

The integrator (solver.transient) gives each term the step h and the start state
(u_n, v_n) through ``prepare``; in terms of u = u_{n+1} the backward Euler increments are

    Inertia:  r += M (u - u_n - h v_n) / h^2,   K += M / h^2,
              Psi = (u - u_n - h v_n)^T M (u - u_n - h v_n) / (2 h^2)
    Damping:  r += C (u - u_n) / h,             K += C / h,
              Psi = (u - u_n)^T C (u - u_n) / (2 h)
"""

import numpy as np
import scipy.sparse as sp

from ..assembly import block_dofs
from ..element import N_GP
from ..kernels.brick import brick_forces
from .base import Term


def lumped_masses(mesh, density):
    """(n,) nodal masses (tonne) for density in tonne/mm^3."""
    w = density * np.einsum("ga,mg->ma", N_GP, mesh.det_j)          # (m, 8)
    return np.bincount(mesh.bricks.ravel(), weights=w.ravel(), minlength=mesh.n_nodes)


class Inertia(Term):
    """M a with lumped masses (diagonal: no blocks of its own)."""

    name = "inertia"

    def __init__(self, mesh, density):
        self.mass = lumped_masses(mesh, density)
        self.m3 = np.repeat(self.mass, 3)                         # (3 n,)
        self.h = None

    def prepare(self, h, u_n, v_n):
        self.h, self.u_pred = h, (u_n + h * v_n).ravel()

    def assemble(self, state, asm, block_ids):
        d = state.u.ravel() - self.u_pred
        f = self.m3 * d / self.h ** 2
        asm.residual += f
        asm.energy += 0.5 * float(d @ f)
        asm.add_diagonal(self.m3 / self.h ** 2)

    def kinetic_energy(self, v):
        return 0.5 * float(self.m3 @ (v.ravel() ** 2))


def passive_tangent(elasticity, ndof):
    """K0: the elasticity term's tangent at u = 0, as a CSR matrix (ndof, ndof)."""
    m = len(elasticity.bricks)
    fe, ke = np.empty((m, 24)), np.empty((m, 24, 24))
    brick_forces(np.zeros((ndof // 3, 3)), elasticity.bricks, elasticity._dndX, elasticity._w,
                 elasticity.params, elasticity.form, True, fe, ke, np.empty(m), np.empty(m))
    d = block_dofs(elasticity.bricks)
    rows = np.repeat(d, 24, axis=1).ravel()
    cols = np.tile(d, (1, 24)).ravel()
    K = sp.csr_matrix((ke.ravel(), (rows, cols)), shape=(ndof, ndof))
    K.sum_duplicates()
    return K


class Damping(Term):
    """C v with C = alpha M + beta K0 (K0 from ``passive_tangent``)."""

    name = "damping"

    def __init__(self, mass3, alpha, beta, K0):
        self.alpha, self.beta = alpha, beta
        self.m3, self.K0 = mass3, K0.tocoo()
        self._K0csr = K0.tocsr()
        self._pattern, self._idx = None, None
        self.h = None

    def prepare(self, h, u_n, v_n):
        self.h, self.u_n = h, u_n.ravel().copy()

    def force(self, v):
        """C v (3 n,) for a velocity v."""
        v = v.ravel()
        return self.alpha * self.m3 * v + self.beta * (self._K0csr @ v)

    def assemble(self, state, asm, block_ids):
        v = (state.u.ravel() - self.u_n) / self.h
        f = self.force(v)
        asm.residual += f
        asm.energy += 0.5 * self.h * float(v @ f)
        if asm.need_k:
            if self._pattern is not asm.pattern:
                self._pattern = asm.pattern
                self._idx = asm.pattern.locate(self.K0.row, self.K0.col)
            asm.add_diagonal(self.alpha * self.m3 / self.h)
            asm.data[self._idx] += (self.beta / self.h) * self.K0.data
