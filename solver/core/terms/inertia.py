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

The integrator (solver.core.transient) gives each term its substep through ``prepare``
(a solver.core.transient.Stage): a linear multistep method writes the end state's velocity
and acceleration as v = c (u - u_d) and a = c (v - v_d') = c^2 (u - u_m), with c (1/s) and
the points u_d, u_m (mm) set by the method and the history (backward Euler: c = 1/h,
u_d = u_n, u_m = u_n + h v_n). In terms of u = u_{n+1}:

    Inertia:  r += c^2 M (u - u_m),   K += c^2 M,   Psi = c^2 (u - u_m)^T M (u - u_m) / 2
    Damping:  r += c C (u - u_d),     K += c C,     Psi = c (u - u_d)^T C (u - u_d) / 2

with C built on the stage's configuration u_g (u_n for backward Euler; the predicted end
state for BDF2, so that the damping matrix's change over a step costs no order).
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
        self.c = None

    def prepare(self, stage):
        """Start a substep (solver.core.transient.Stage): a = c^2 (u - stage.u_m)."""
        self.c, self.u_pred = stage.c, stage.u_m

    def assemble(self, state, asm, block_ids):
        d = state.u.ravel() - self.u_pred
        f = (self.c ** 2) * self.m3 * d
        asm.residual += f
        asm.energy += 0.5 * float(d @ f)
        asm.add_diagonal((self.c ** 2) * self.m3)

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
        self.c = None
        self.builds = 0
        self.generation = 0             # counts the K_n due (prepare); a part of Newton's key
        self._due = False

    def blocks(self):
        return [self.elasticity.bricks]

    def prepare(self, stage):
        """Start a substep (solver.core.transient.Stage): v = c (u - stage.u_d); K_n is due
        for a rebuild (a new ``generation``) on stage.u_g when a node of it lies more than
        refresh from the last build's."""
        self.c, self.u_n, self._u_g = stage.c, stage.u_d, stage.u_g.reshape(-1, 3)
        if self.beta and (self.u_geom is None
                          or np.abs(self._u_g - self.u_geom).max() > self.refresh):
            self.generation += 1
            self._due = True

    def _update(self, pattern, block):
        """Build K_n (CSR data over pattern) on the stage's configuration when due."""
        if not (self._due or self._pattern is not pattern) or self.beta == 0.0:
            self._pattern = pattern
            return
        u_n = self._u_g
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
        v = self.c * (state.u.ravel() - self.u_n)
        f = self.force(v)
        asm.residual += f
        asm.energy += 0.5 * float(v @ f) / self.c
        if asm.need_k:
            asm.add_diagonal(self.c * self.alpha * self.m3)
            if self.beta:
                asm.data += (self.c * self.beta) * self._kdata
