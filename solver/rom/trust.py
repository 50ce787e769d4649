r"""The trust check of a reduced state: the full-order residual of u = V q + L, relative
(L: the jaw's lifting, solver.rom.lifting).

After a substep with v = c (u - u_d), a = c^2 (u - u_m) (solver.rom.stepper; backward
Euler c = 1 / h, u_d = u_n, u_m = u_n + h v_n), on the free DOFs, with inertia and damping
(C = alpha M + beta K_n, K_n on all bricks at the stepper's damping shape; K_0 with
damping "rest"):

    R = c^2 M (u - u_m) + c C (u - u_d) + f_int(u) + cables + stiffening + contact,
    rho = |R_free| / max(|f_tissue|, |f_cables|, 1e-3 N),

the cables and contact by the full model's own terms (solver.core.system.System, built once, at
construction), the tissue and stiffening bricks of the whole mesh by
solver.rom.online_kernels.brick_forces_full (the same forces as the elasticity and
stiffening terms: tests/test_rom_online.py); K_n (u - u_n) is applied without forming the
element matrices (passive_apply, D0 the law's tangent at C = 1 per brick).
rho above the model's trust threshold means that the reduced state has left the span the
model was trained on (solver.rom.simulation).
"""

import numpy as np

from solver.core.assembly import Assembly
from solver.core.system import System
from solver.core.terms.inertia import lumped_masses, passive_tangent
from solver.rom.online import small_strain_tangents
from solver.rom.damping_kernels import passive_apply
from solver.rom.online_kernels import brick_forces_full


class TrustCheck:
    """sim: the solver.rom.simulation.ReducedSimulation (its face model and scene);
    alpha, beta, m_scale: its damping constants and inertia scale; damping: 'rest' |
    'current'."""

    def __init__(self, sim, density, alpha, beta, m_scale, damping):
        model = sim.face.model
        self.face = sim.face
        prescribed = model.system().prescribed
        terms = [t for t in model.terms if t.name not in ("inertia", "damping")]
        self.sysm_all = System(terms, sim.anatomy.mesh.n_nodes, prescribed)   # reference
        self.st = sim.face.stiffening
        fast = [model.elasticity] + ([self.st] if self.st is not None else [])
        others = [t for t in terms if not any(t is f for f in fast)]
        self.sysm = System(others, sim.anatomy.mesh.n_nodes, prescribed)
        self.m3 = np.repeat(lumped_masses(sim.anatomy.mesh, density), 3)
        self.free = self.sysm.free
        self.alpha, self.beta, self.m_scale, self.damping = alpha, beta, m_scale, damping
        el = model.elasticity
        self.el = el
        if damping == "current":
            self.D0, self.kvol = small_strain_tangents(el.params, el.form)
        else:
            from solver.core.kernels.scatter import scatter_matrices
            pattern = self.sysm_all.pattern
            asm = Assembly(pattern, True)
            scatter_matrices(passive_tangent(el), pattern.index[0], asm.data)
            self.K0 = pattern.matrix(asm.data)
        self.cables = sim.face.cables
        self._kdu = np.zeros((sim.anatomy.mesh.n_nodes, 3))
        self._fb = np.zeros((sim.anatomy.mesh.n_nodes, 3))
        m = len(el.bricks)
        self.sparams = np.zeros((m, 6))
        self.s = np.zeros(m)
        if self.st is not None:
            pos = np.searchsorted(el.subset, self.st.subset)
            self._stpos = pos
            self.sparams[pos, 0], self.sparams[pos, 2] = self.st._c[:, 0], self.st._c[:, 1]

    def internal_forces(self, u):
        """(3 n,) the full model's internal forces at u (3 n,) (all terms but inertia and
        damping), the bricks by brick_forces_full; keeps the cables' apart (f_cables)."""
        el = self.el
        if self.st is not None:
            self.s[self._stpos] = self.st.factors(1.0) - 1.0
        self._fb[:] = 0.0
        jmin = brick_forces_full(u.reshape(-1, 3), el.bricks, el._dndX, el._w, el.params,
                                 self.sparams, self.s, el.form, self._fb)
        if not jmin > 0.0:
            raise FloatingPointError("an inverted brick in the reduced state")
        sysm = self.sysm
        sysm.lam = 1.0
        st = sysm.state(u)
        f = self._fb.ravel().copy()
        self.f_cables = np.zeros_like(f)
        for term, ids in zip(sysm.terms, sysm._ids):
            asm = Assembly(sysm.pattern, False)
            term.assemble(st, asm, ids)
            f += asm.residual
            if term is self.cables:
                self.f_cables = asm.residual
        return f

    def passive_apply(self, u_n, du):
        """K_n du (3 n,) with K_n on the shape X + u_n (both (3 n,))."""
        el = self.el
        self._kdu[:] = 0.0
        jmin = passive_apply(u_n.reshape(-1, 3), du.reshape(-1, 3), el.bricks, el._dndX,
                             el._w, self.D0, self.kvol, el.form, self._kdu)
        if not jmin > 0.0:
            raise FloatingPointError("an inverted brick in the damping's shape")
        return self._kdu.ravel().copy()

    def residual(self, V, q, q_n, v_n, h, L=0.0, L_n=0.0, stage=None):
        """rho (module docstring) of u = V q + L after the substep from (q_n, v_n), step h
        (L, L_n (n, 3): the lifting at the substep's end and start; the cables and the
        teeth at the jaw's target pose, the end of the caller's step). stage: the
        substep's solver.rom.stepper.StageR (BDF2: v = c (u - u_d), a = c^2 (u - u_m),
        u_d = V q_d + L_d, u_m = V q_m + L_d, K_n on the predicted shape V p + L); None:
        backward Euler's c = 1 / h, u_d = u_n, u_m = u_n + h V v_n, K_n at u_n."""
        u = V @ q + np.ravel(L)
        if stage is None or stage.coef[2] == 0.0:
            c = 1.0 / h
            u_d = V @ q_n + np.ravel(L_n)
            u_m, shape = u_d + h * (V @ v_n), u_d
        else:
            c = stage.c
            L_d = np.ravel(stage.L_d)
            u_d, u_m = V @ stage.q_d + L_d, V @ stage.q_m + L_d
            shape = V @ stage.p + np.ravel(L)
        f = self.internal_forces(u)
        f_cab = self.f_cables
        du = c * (u - u_d)
        if self.damping == "current" and self.beta:
            kdu = self.passive_apply(shape, du)
        elif self.beta:
            kdu = self.K0 @ du
        else:
            kdu = 0.0 * du
        R = f + self.m_scale * (c * c) * self.m3 * (u - u_m) + self.alpha * self.m3 * du \
            + self.beta * kdu
        free = self.free
        scale = max(float(np.linalg.norm((f - f_cab)[free])),
                    float(np.linalg.norm(f_cab[free])), 1e-3)
        return float(np.linalg.norm(R[free])) / scale
