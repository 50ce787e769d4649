r"""The reference implementation of the reduced step: the oracle of the fast online step
(solver.rom.online, solver.rom.stepper), which tests/test_rom_online.py compares with it.

ReferenceOperator adds to solver.rom.reduced.ReducedOperator the forces and tangents in
reduced coordinates, evaluated the plain way:

    R(q) = M_r (q - q_n - h v_n) / h^2 + C_r (q - q_n) / h
           + f_bricks(q, a) + f_cables(q, a) + f_contact(q) = 0,
    dR/dq = M_r / h^2 + C_r / h + K_bricks + K_cables + K_contact,

* tissue and activation stiffening: the cubature's bricks by the general element kernels
  (solver.rom.kernels.reduced_bricks), sum_e w_e V_e^T (f_e + s_e(a) f^s_e);
* cables: with l, n, the tension T = AE (l / L0 - 1 + e_c(a))^+,
  f_r = sum_c T D_c^T n, K_r = sum_c D_c^T (AE/L0 n n^T + T/l (I - n n^T)) D_c;
* contact: the penalty terms themselves (solver.face.terms.contact) on displacements
  reconstructed at their nodes only, their element blocks projected with the rows of V:
  f_r = sum_b V_b^T f_b, K_r = sum_b V_b^T K_b V_b.

ReferenceStepper steps them with backward Euler at fixed substeps: full Newton (the
contact and cable tangents at every iteration, the bricks' every `refresh` substeps) with
C_r = alpha M_r + beta V^T K_n V rebuilt every `damping_refresh` substeps on the start
shape. reference_simulation() puts both into a ReducedSimulation.
"""

import numpy as np
import scipy.linalg as sla

from solver.core.assembly import block_dofs
from solver.core.terms.base import State
from solver.rom.kernels import reduced_bricks
from solver.rom.reduced import ReducedOperator
from solver.rom.stepper import H_MAX_BE, Stepper


class _Capture:
    """An Assembly stand-in for the contact terms: keeps their element blocks."""

    def __init__(self, need_k):
        self.need_k, self.energy, self.blocks = need_k, 0.0, []

    def add_block(self, block, fe, ke=None, rows=None):
        self.blocks.append((block, fe, ke, rows))


class ReferenceOperator(ReducedOperator):
    """ReducedOperator with its forces and tangents evaluated the plain way (module
    docstring); the same arguments."""

    def __init__(self, *args):
        super().__init__(*args)
        self._contact_setup()
        self.fr, self.kr = np.zeros(self.r), np.zeros((self.r, self.r))

    def _contact_setup(self):
        self.cblocks = []              # per term, per block: (k, 3 nloc, r) basis rows
        nodes = []
        for term in self.contact:
            bl = term.blocks()
            self.cblocks.append([np.ascontiguousarray(
                self.V[block_dofs(b)]) for b in bl])
            nodes += [np.asarray(b).ravel() for b in bl]
        self.cnodes = np.unique(np.concatenate(nodes)) if nodes else np.zeros(0, np.int64)
        self.Vc = np.ascontiguousarray(self.Vn[self.cnodes])
        self._uc = np.zeros((self.mesh.n_nodes, 3))

    def bricks_part(self, q, a, need_k):
        """(f_r, K_r or None, min det F) of the cubature at q for activations a (10,)."""
        s = self.stiffening_factors(a)
        jmin = reduced_bricks(q, self.Ve, self.le, self.weights, self.dndX, self.wgp,
                              self.params,
                              self.form, self.sparams, s, need_k, self.fr, self.kr)
        return self.fr.copy(), (self.kr.copy() if need_k else None), jmin

    def cables_part(self, q, a, need_k):
        if self.ncab == 0:
            return np.zeros(self.r), (np.zeros((self.r, self.r)) if need_k else None)
        d = self.d0 + self.D @ q                                   # (c, 3)
        l = np.sqrt((d * d).sum(axis=1))
        n = d / l[:, None]
        s = l / self.L0 - 1.0 + a[self.cab_muscle] * self.cab_unit
        on = s > 0.0
        T = np.where(on, self.AE * s, 0.0)
        self.tension = T
        Dn = np.einsum("cir,ci->cr", self.D[on], n[on])            # (c_on, r)
        f = Dn.T @ T[on]
        if not need_k:
            return f, None
        Ton, lon = T[on], l[on]
        # D^T (AE/L0 - T/l) n n^T D + T/l D^T D
        K = (Dn.T * ((self.AE[on] / self.L0[on]) - Ton / lon)) @ Dn
        Dw = self.D[on] * np.sqrt(Ton / lon)[:, None, None]
        K += np.einsum("cir,cis->rs", Dw, Dw)
        return f, K

    def reconstruct_contact(self, q):
        """(n, 3) displacements filled at the contact nodes only (zero elsewhere)."""
        self._uc[self.cnodes] = self.Vc @ q + self.L[self.cnodes]
        return self._uc

    def contact_part(self, q, need_k, t=0.0):
        f = np.zeros(self.r)
        K = np.zeros((self.r, self.r)) if need_k else None
        if not self.contact:
            return f, K
        st = State(self.reconstruct_contact(q), self.lam, t, {})
        for term, vb in zip(self.contact, self.cblocks):
            cap = _Capture(need_k)
            term.assemble(st, cap, list(range(len(vb))))
            for block, fe, ke, rows in cap.blocks:
                Vb = vb[block] if rows is None else vb[block][rows]
                if len(Vb) == 0:
                    continue
                if rows is None:                     # all slaves: keep the active ones
                    on = np.flatnonzero(np.abs(fe).max(axis=1) > 0)
                    Vb, fe = Vb[on], fe[on]
                    ke = ke[on] if ke is not None else None
                if len(Vb) == 0:
                    continue
                Vf = Vb.reshape(-1, self.r)
                f += Vf.T @ fe.ravel()
                if need_k and ke is not None:
                    K += Vf.T @ (ke @ Vb).reshape(-1, self.r)
        return f, K

    def forces(self, q, a, need_k, t=0.0):
        """Internal forces (no inertia, damping): (f_r, K_r or None, min det F)."""
        fb, kb, jmin = self.bricks_part(q, a, need_k)
        fc, kc = self.cables_part(q, a, need_k)
        fk, kk = self.contact_part(q, need_k, t)
        f = fb + fc + fk
        return f, (kb + kc + kk if need_k else None), jmin



class ReferenceStepper(Stepper):
    """Backward Euler at fixed substeps of h_max with full Newton on a ReferenceOperator
    (module docstring); refresh: substeps between the bricks' tangents; damping_refresh:
    substeps between the damping matrix's builds."""

    def __init__(self, op, M_r, alpha, beta, damping="current", h_max=H_MAX_BE, utol=1e-4,
                 max_iter=20, refresh=4, damping_refresh=5):
        super().__init__(op, M_r, alpha, beta, damping, h_max, utol, max_iter,
                         integrator="backward_euler", tol=None)
        self.online = None
        self.refresh, self.damping_refresh = refresh, int(damping_refresh)
        self.reset_caches()

    def reset_caches(self):
        super().reset_caches()
        self._damping_age = 10 ** 9             # rebuild C_r at the next substep
        self._kb = None                         # the bricks' tangent
        self._since_refresh, self._last_iters = 10 ** 9, 0

    @property
    def penetration(self):
        return 0.0                              # not measured here

    @property
    def contact_force(self):
        return float(sum(getattr(t, "total_force", 0.0) for t in self.op.contact))

    def _before_substep(self, q_n):
        """C_r rebuilt every damping_refresh substeps on the shape at q_n."""
        if self.damping != "current" or not self.beta:
            return
        if self._damping_age >= self.damping_refresh:
            self.C_r = self.alpha * self.M_damp + self.beta * self.op.passive_stiffness(q_n)
            self.op.C_r = self.C_r
            self._damping_age = 0
            self.stats["damping_builds"] += 1
        self._damping_age += 1

    def _newton(self, q_n, v_n, h, a, t, stage=None):
        q, its, why = self._full_newton(q_n, v_n, h, a, t)
        if q is None:
            self._kb = None                   # a failed substep: a fresh tangent next
        return q, its, why

    def _full_newton(self, q_n, v_n, h, a, t):
        op = self.op
        A = self.M_r / h ** 2 + self.C_r / h
        q = q_n + h * v_n
        b = self.M_r @ (q_n + h * v_n) / h ** 2 + self.C_r @ q_n / h
        if op.moving and self.beta:       # the jaw's motion damped through the tissue
            b = b - (self.beta / h) * op.lifting_damping(q_n)
        refresh = (self._kb is None or self._since_refresh >= self.refresh
                   or self._last_iters > 3)
        r_prev, dq_prev = np.inf, None
        for it in range(1, self.max_iter + 1):
            need_b = refresh and it == 1
            fb, kb, jmin = op.bricks_part(q, a, need_b)
            if not jmin > 0.0:
                return None, it, "inverted brick"
            if need_b:
                self._kb, self._since_refresh = kb, 0
            fc, kc = op.cables_part(q, a, True)
            fk, kk = op.contact_part(q, True, t)
            R = A @ q - b + fb + fc + fk
            rn = float(np.linalg.norm(R))
            if rn > r_prev and dq_prev is not None:
                dq_prev = 0.5 * dq_prev
                q = q - dq_prev
                if float(np.linalg.norm(dq_prev)) <= self.utol:
                    self._since_refresh += 1
                    self._last_iters = it
                    return q, it, ""
                continue
            J = A + self._kb + kc + kk
            try:
                dq = -sla.solve(J, R, assume_a="sym", check_finite=False)
            except (sla.LinAlgError, ValueError):
                return None, it, "singular reduced tangent"
            if not np.all(np.isfinite(dq)):
                return None, it, "NaN"
            q = q + dq
            r_prev, dq_prev = rn, dq
            if float(np.linalg.norm(dq)) <= self.utol:
                self._since_refresh += 1
                self._last_iters = it
                return q, it, ""
        return None, self.max_iter, f"no convergence in {self.max_iter} iterations"


def reference_simulation(rom, refresh=4, damping_refresh=5):
    """The ReducedSimulation rom (a solver.rom.simulation.ReducedSimulation, at rest) with
    its operator and stepper replaced by the reference ones, at its h, utol and max_iter
    (the reference steps with backward Euler at fixed substeps of rom.h_max)."""
    op, st = rom.op, rom.stepper
    rom.op = ReferenceOperator(rom.full, op.V, op.bricks, op.weights, op.M_r, op.C_r)
    rom.stepper = ReferenceStepper(rom.op, st.M_damp, st.alpha, st.beta, st.damping,
                                   rom.h_max, st.utol, st.max_iter, refresh,
                                   damping_refresh)
    return rom
