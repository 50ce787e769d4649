r"""Inertia and Rayleigh damping for implicit time stepping.

Mass: lumped, the row sums of the consistent brick mass matrix,
m_a = rho sum_e sum_g N_a(xi_g) det J_g w_g (positive for trilinear bricks and wedges),
so M is diagonal: cheap, and no spurious coupling through the mass.

Damping: C = alpha M + beta K_n with K_n the tangent of the passive tissue at zero strain
on the configuration x_n = X + u_n at the start of the substep: the small-strain stiffness
of the current shape (updated Lagrangian), K_n = sum_e int B_n^T D B_n dv_n. It is
symmetric and positive semi-definite at every state (P = v^T C v >= 0) and objective: a
rigid rotation of the tissue is not damped, and an isochoric motion of the deformed tissue
meets the shear modulus, not the bulk one. The rest tangent K0 (beta K0 v) is not: where the
tissue has turned, K0 reads part of an isochoric rate as a volume change and resists it with
the bulk modulus (2/d = 500 times the shear modulus), so that a face held under OOP + BUC
at 0.5 (no contact) creeps towards its static equilibrium over tens of seconds of
simulated time, where with K_n it settles within half a second. K_n is rebuilt when a
node has moved more than ``refresh`` (mm) since the last build, once per substep at most,
and is held fixed within the substep, so the step stays a linear damper:
r += C (u - u_n) / h, K += C / h. Passive: the stiffening of active muscle does not raise the damping. The current full tangent would
follow stiffening, but it can lose definiteness (and with it dissipation) under compression
and contact; with alpha = 40 1/s and beta = 0.03 s every mode is overdamped anyway.

The integrator (solver.core.transient) gives each term the step h and the start state
(u_n, v_n) through ``prepare``; in terms of u = u_{n+1} the backward Euler increments are

    Inertia:  r += M (u - u_n - h v_n) / h^2,   K += M / h^2,
              Psi = (u - u_n - h v_n)^T M (u - u_n - h v_n) / (2 h^2)
    Damping:  r += C (u - u_n) / h,             K += C / h,       (C built on x_n)
              Psi = (u - u_n)^T C (u - u_n) / (2 h)
"""

import numpy as np

from solver.core.element import N_GP, reference_geometry
from solver.core.kernels.mooney_rivlin import small_strain_moduli
from solver.core.kernels.scatter import scatter_matrices
from solver.core.kernels.small_strain import small_strain_stiffness
from solver.core.terms.base import Term


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


def passive_tangent(elasticity, u=None):
    """Element tangents (m, 24, 24) of the elasticity term's bricks at zero strain on the
    configuration X + u (u (n, 3), default 0: the reference one)."""
    nodes = elasticity.mesh.nodes if u is None else elasticity.mesh.nodes + u
    det, dndx = reference_geometry(nodes, elasticity.bricks)
    mu, kappa = small_strain_moduli(elasticity.params.T)
    ke = np.empty((len(elasticity.bricks), 24, 24))
    small_strain_stiffness(dndx, det, np.ascontiguousarray(mu), np.ascontiguousarray(kappa),
                           elasticity.form, ke)
    return ke


class Damping(Term):
    """C v with C = alpha M + beta K_n (see the module docstring).

    mass3 (3 n,) lumped masses per DOF; elasticity: the passive tissue term whose bricks and
    law give K_n; refresh (mm): largest node motion before K_n is rebuilt.
    """

    name = "damping"

    def __init__(self, mass3, alpha, beta, elasticity, refresh=0.0):
        self.alpha, self.beta = alpha, beta
        self.m3, self.elasticity, self.refresh = mass3, elasticity, refresh
        self.u_geom = None              # (n, 3) the configuration K_n was built on
        self._pattern, self._kdata = None, None
        self.h = None
        self.builds = 0
        self.generation = 0             # counts the K_n due (prepare); a part of Newton's key
        self._due = False

    def blocks(self):
        return [self.elasticity.bricks]

    def prepare(self, h, u_n, v_n):
        """Start a substep from (u_n, v_n): K_n is due for a rebuild (a new ``generation``)
        when a node moved more than refresh since the last build."""
        self.h, self.u_n = h, u_n.ravel().copy()
        if self.beta and (self.u_geom is None
                          or np.abs(u_n - self.u_geom).max() > self.refresh):
            self.generation += 1
            self._due = True

    def _update(self, pattern, block):
        """Build K_n (CSR data over pattern) on the substep's start state when due."""
        if not (self._due or self._pattern is not pattern) or self.beta == 0.0:
            self._pattern = pattern
            return
        u_n = self.u_n.reshape(-1, 3)
        self._kdata = np.zeros(pattern.nnz)
        scatter_matrices(passive_tangent(self.elasticity, u_n), pattern.index[block],
                         self._kdata)
        self._K = pattern.matrix(self._kdata)          # built once per K_n, not per residual
        self._pattern, self.u_geom, self._due = pattern, u_n.copy(), False
        self.builds += 1

    def force(self, v):
        """C v (3 n,) for a velocity v (3 n,), with the C of the last assembly."""
        v = v.ravel()
        f = self.alpha * self.m3 * v
        if self.beta and self._kdata is not None:
            f += self.beta * (self._K @ v)
        return f

    def assemble(self, state, asm, block_ids):
        self._update(asm.pattern, block_ids[0])
        v = (state.u.ravel() - self.u_n) / self.h
        f = self.force(v)
        asm.residual += f
        asm.energy += 0.5 * self.h * float(v @ f)
        if asm.need_k:
            asm.add_diagonal(self.alpha * self.m3 / self.h)
            if self.beta:
                asm.data += (self.beta / self.h) * self._kdata
