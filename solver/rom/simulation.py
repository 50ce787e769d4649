r"""`Simulation(scene, fidelity="realtime")`: the reduced model behind Simulation's API.

The full-order Simulation of the scene is built as usual (coarse generic half face,
solver.fidelity.REDUCED["realtime"]): it provides the anatomy, terms, activations and lip
outputs, and it is the fallback. Its reduced model (solver.rom.store) is looked up by the
scene's key; where none is cached, ModelNotTrained names the training command
(`rom_train=True` trains one on demand, with a message, in this process).

Time stepping: backward Euler in reduced coordinates (solver.rom.reduced) at fixed
substeps of at most h = 1 ms, activations ramping within a caller's step as in the full
model (hold "ramp"). Newton on the r x r system: the bricks' reduced tangent is
refreshed at the first iteration of a substep every `refresh` substeps (and whenever the
last substep needed more than 3 iterations); cables and contact (stiff, switching) give
fresh tangents at every iteration. Converged when |dq| <= utol (mm; V is orthonormal so
this is the displacement correction's Euclidean norm). A substep that does not converge
in max_iter iterations (or inverts a brick) is split in four, twice at most.

Damping: C = alpha M + beta K_n as in the full model, K_n the passive small-strain
stiffness on the shape at the start of a substep, hyper-reduced by the cubature
(V^T K_n V ~ sum_e w_e V_e^T K_n,e V_e) and rebuilt every `damping_refresh` substeps
(damping="current", default); damping="rest" keeps the constant V^T K_0 V (cheaper, but
0.3-0.6 mm off the full model on training patterns: the rest K_0 damps turned tissue
with the bulk modulus, solver/terms/inertia.py).

Trust check: every `check_every` substeps, the full-order residual of the reduced
solution u = V q on the free DOFs, with inertia and damping (M (u - u_n - h v_n) / h^2 +
(alpha M + beta K_n)(u - u_n) / h + f_int(u) + cables + stiffening + contact, K_n on all
bricks at u_n, or K_0 with damping="rest"), relative to the force scale
max(|f_tissue|, |f_cables|, 1e-3 N):

    rho = |R_free(V q)| / scale.

rho above the model's trust threshold (calibrated in training: a multiple of the largest
rho met on training patterns) means the state has left the span the model was trained
on. trust="fallback" (default): a warning, the caller's step is redone by the full model
from the reduced state at its start, and the simulation stays full-order from then on
(`mode` = "full"); "warn": a warning only; "off": no check. A substep that fails after
every split also falls back (or fails, with trust "warn"/"off").
"""

import math
import warnings

import numpy as np
import scipy.linalg as sla

from ..errors import ParameterError
from ..simulation import Simulation
from ..system import System
from ..transient import StepStats
from .reduced import ReducedOperator
from .store import ModelNotTrained, find_model, load_model, model_path

TRUST_MODES = ("fallback", "warn", "off")


class TrustWarning(UserWarning):
    """The reduced solution left the range the model was trained on."""


class ReducedSimulation(Simulation):
    """Extra keyword arguments (besides Simulation's): rom_model (a .npz path or an
    (arrays, meta) pair: use this model whatever the scene's key), rom_train (train on
    demand when no model is cached), trust ('fallback' | 'warn' | 'off'), check_every
    (substeps between trust checks), h (largest substep, s), refresh, utol, max_iter;
    damping 'rest' (C_r constant) or 'current' (K_n by the cubature on the shape at the
    start of a substep, rebuilt every damping_refresh substeps)."""

    def __init__(self, scene="default", loaded_anatomy=None, fidelity="realtime",
                 rom_model=None, rom_train=False, trust="fallback", check_every=50, h=1e-3,
                 refresh=4, utol=1e-4, max_iter=20, damping="current", damping_refresh=5,
                 **overrides):
        if damping not in ("rest", "current"):
            raise ParameterError(f"damping = {damping!r} is not 'rest' or 'current'")
        self.damping_mode, self.damping_refresh = damping, int(damping_refresh)
        if trust not in TRUST_MODES:
            raise ParameterError(f"trust = {trust!r} is not one of {TRUST_MODES}")
        super().__init__(scene, loaded_anatomy, fidelity=fidelity, **overrides)
        sc = self.scene
        if sc.analysis != "transient" or sc.gravity != "none" or not (sc.inertia or sc.damping):
            raise ParameterError("fidelity 'realtime' runs transient scenes without gravity "
                                 f"(scene {sc.name!r}: analysis {sc.analysis!r}, gravity "
                                 f"{sc.gravity!r}); use fidelity 'fast'")
        if rom_model is None:
            try:
                arrays, meta = find_model(sc)
            except ModelNotTrained:
                if not rom_train:
                    raise
                from .train import train
                print(f"facefmu: no realtime model for scene {sc.name!r}; training one "
                      f"(full-order snapshot runs, minutes) into {model_path(sc)}", flush=True)
                arrays, meta = load_model(train(sc, sim=self))
        elif isinstance(rom_model, tuple):
            arrays, meta = rom_model
        else:
            arrays, meta = load_model(rom_model)
        self.rom_meta = meta
        self.trust, self.check_every = trust, int(check_every)
        self.h_max, self.refresh, self.utol, self.max_iter = h, refresh, utol, max_iter
        self.trust_threshold = float(arrays["trust_threshold"][0])
        self._setup(arrays)
        self.mode = "rom"
        self.trust_history = []          # (t, rho) of every check

    # -- setup ---------------------------------------------------------------------------
    def _setup(self, arrays):
        V = arrays["V"]
        alpha = self.scene.alpha if self.scene.damping else 0.0
        beta = self.scene.beta if self.scene.damping else 0.0
        m_scale = 1.0 if self.scene.inertia else 0.0
        M_r = arrays["M_r"]
        self.op = ReducedOperator(self, V, arrays["bricks"], arrays["weights"],
                                  m_scale * M_r, alpha * M_r + beta * arrays["K0_r"])
        r = V.shape[1]
        self.q, self.v_r = np.zeros(r), np.zeros(r)
        self._kb = None
        self._since_refresh = 10 ** 9
        self._last_iters = 0
        self._substeps = 0
        self._checker = None
        self._alpha, self._beta = alpha, beta
        self._m_on = m_scale
        self._M_r = M_r

    def _check_setup(self):
        """Full-order residual pieces for the trust check (built on first use)."""
        from ..assembly import Assembly
        from ..terms.inertia import lumped_masses, passive_tangent
        model = self.face.model
        terms = [t for t in model.terms if t.name not in ("inertia", "damping")]
        sysm = System(terms, self.anatomy.mesh.n_nodes, model.system().prescribed)
        m3 = np.repeat(lumped_masses(self.anatomy.mesh, self._density()), 3)
        asm = Assembly(sysm.pattern, True)
        from ..kernels.scatter import scatter_matrices
        scatter_matrices(passive_tangent(model.elasticity), sysm.pattern.index[0], asm.data)
        K0 = sysm.pattern.matrix(asm.data)
        self._checker = (sysm, m3, K0, sysm.free)

    def _density(self):
        from ..units import kg_per_m3
        return kg_per_m3(self.scene.density)

    # -- reduced time stepping -----------------------------------------------------------
    def _newton(self, q_n, v_n, h, a, t):
        op = self.op
        A = op.M_r / h ** 2 + op.C_r / h
        q = q_n + h * v_n
        b = op.M_r @ (q_n + h * v_n) / h ** 2 + op.C_r @ q_n / h
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
                # the residual grew (a contact switching on or off): go back half the step
                # and evaluate there (a cheap backtrack, one evaluation per halving)
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

    def _advance_rom(self, t_end, stats):
        """Reduced substeps from self.t to t_end; True on success (state updated)."""
        t0, span = self.t, t_end - self.t
        act = self.face.activation
        n = max(1, int(math.ceil(span / self.h_max * (1.0 - 1e-9))))
        q, v = self.q.copy(), self.v_r.copy()
        pieces = [(k + 1) / n for k in range(n)]
        lam_prev, depth = 0.0, {}
        i = 0
        while i < len(pieces):
            lam = pieces[i]
            h = (lam - lam_prev) * span
            if self.damping_mode == "current" and self._beta and \
                    (self._substeps + stats.substeps) % self.damping_refresh == 0:
                self.op.C_r = self._alpha * self._M_r + self._beta * self.op.passive_stiffness(q)
            q_new, its, why = self._newton(q, v, h, act.at(lam), t0 + lam * span)
            stats.newton_iterations += its
            if q_new is None:
                d = depth.get(round(lam_prev, 12), 0)
                if d >= 2:
                    stats.reason = f"at t = {t0 + lam * span:.6g} s: {why}"
                    return False
                stats.cutbacks += 1
                self._kb = None
                sub = [lam_prev + (lam - lam_prev) * (k + 1) / 4 for k in range(4)]
                pieces[i:i + 1] = sub
                depth[round(lam_prev, 12)] = d + 1
                continue
            self._last = (q.copy(), v.copy(), h)
            v = (q_new - q) / h
            q = q_new
            lam_prev = lam
            i += 1
            stats.substeps += 1
            stats.h_min, stats.h_max = min(stats.h_min, h), max(stats.h_max, h)
        self.q, self.v_r = q, v
        self._substeps += stats.substeps
        return True

    def trust_residual(self):
        """rho (module docstring) at the current reduced state (after a substep)."""
        if self._checker is None:
            self._check_setup()
        sysm, m3, K0, free = self._checker
        q_n, v_n, h = self._last
        V = self.op.V
        u, un = V @ self.q, V @ q_n
        sysm.lam = 1.0
        f = sysm.residual(u)
        f_cab = np.zeros_like(f)
        if self.face.cables is not None:
            from ..assembly import Assembly
            asm = Assembly(sysm.pattern, False)
            i = sysm.terms.index(self.face.cables)
            self.face.cables.assemble(sysm.state(u), asm, sysm._ids[i])
            f_cab = asm.residual
        du = (u - un) / h
        if self.damping_mode == "current" and self._beta:
            from ..terms.inertia import passive_tangent
            el = self.face.model.elasticity
            ke = passive_tangent(el, un.reshape(-1, 3))
            dofs = (3 * el.bricks[:, :, None] + np.arange(3)).reshape(len(el.bricks), 24)
            kdu = np.bincount(dofs.ravel(), np.einsum("eij,ej->ei", ke, du[dofs]).ravel(),
                              minlength=len(u))
        else:
            kdu = K0 @ du
        R = f + self._m_on * m3 * (u - un - h * (V @ v_n)) / h ** 2 \
            + self._alpha * m3 * du + self._beta * kdu
        scale = max(float(np.linalg.norm((f - f_cab)[free])),
                    float(np.linalg.norm(f_cab[free])), 1e-3)
        return float(np.linalg.norm(R[free])) / scale

    def _to_full(self, q, v, activation_start):
        """Hand the reduced state to the full model (from then on, mode 'full')."""
        self.face.model.u = self.op.displacement(q).copy()
        self.integrator.v = self.op.displacement(v).copy()
        self.integrator.t = self.t
        self.face.activation.start = activation_start
        for term in self.contact:
            if hasattr(term, "reset"):
                term.reset()
        self.mode = "full"

    def step(self, t_end):
        """Advance to t_end; StepStats (converged False leaves the state at its start)."""
        if self.mode == "full":
            return super().step(t_end)
        if not (np.isfinite(t_end) and t_end > self.t):
            raise ParameterError(f"step end {t_end!r} must be after the current time "
                                 f"{self.t!r}")
        act = self.face.activation
        start = (self.q.copy(), self.v_r.copy(), act.start.copy(), self._substeps)
        stats = StepStats()
        ok = self._advance_rom(t_end, stats)
        rho = None
        if ok and self.trust != "off" and self._substeps // self.check_every \
                > start[3] // self.check_every:
            rho = self.trust_residual()
            self.trust_history.append((float(t_end), rho))
        bad = not ok or (rho is not None and rho > self.trust_threshold)
        if bad:
            what = (f"reduced step failed ({stats.reason})" if not ok else
                    f"full-order residual of the reduced state {rho:.3g} (relative) above "
                    f"the trust threshold {self.trust_threshold:.3g}")
            if self.trust == "fallback":
                warnings.warn(f"realtime model at t = {t_end:.4g} s: {what}; switching to "
                              "the full model", TrustWarning, stacklevel=2)
                self.q, self.v_r = start[0], start[1]
                self._to_full(start[0], start[1], start[2])
                stats = super().step(t_end)
                stats.reason = (stats.reason + "; " if stats.reason else "") + \
                    "fell back to the full model"
                return stats
            if not ok:
                self.q, self.v_r = start[0], start[1]
                act.target = act.start.copy()
                stats.converged = False
                self.last = stats
                return stats
            warnings.warn(f"realtime model at t = {t_end:.4g} s: {what}", TrustWarning,
                          stacklevel=2)
        act.commit()
        self.t = float(t_end)
        self.last = stats
        return stats

    # -- outputs and state ---------------------------------------------------------------
    def outputs(self):
        if self.mode == "full":
            out = super().outputs()
        else:
            u = self.op.displacement(self.q)
            out = self.face.lip_outputs(u)
            out["contact_force"] = float(sum(getattr(t, "total_force", 0.0)
                                             for t in self.contact))
            out["newton_iterations"] = self.last.newton_iterations
            out["substeps"] = self.last.substeps
            out["cutbacks"] = self.last.cutbacks
            if "muscle_strains" in self.scene.record:
                for m, (lo, hi) in self.face.region_strains(u).items():
                    out[f"strain_min_{m}"], out[f"strain_max_{m}"] = lo, hi
        return out

    @property
    def u(self):
        """(n, 3) the current displacements (reconstructed in mode 'rom')."""
        return self.face.u if self.mode == "full" else self.op.displacement(self.q)

    def get_state(self):
        if self.mode == "full":
            return {**super().get_state(), "mode": "full"}
        return {"t": self.t, "u": self.op.displacement(self.q).copy(),
                "v": self.op.displacement(self.v_r).copy(),
                "activation": self.face.activation.start.copy(), "h": self.h_max,
                "q": self.q.copy(), "v_r": self.v_r.copy(), "mode": "rom"}

    def set_state(self, state):
        if state.get("mode", "rom") == "full":
            super().set_state(state)
            self.mode = "full"
            return
        self.mode = "rom"
        self.t = float(state["t"])
        V = self.op.V
        self.q = np.array(state["q"], float) if "q" in state else \
            V.T @ np.asarray(state["u"], float).ravel()
        self.v_r = np.array(state["v_r"], float) if "v_r" in state else \
            V.T @ np.asarray(state["v"], float).ravel()
        self.face.activation.start = np.array(state["activation"], dtype=float)
        self.face.activation.target = self.face.activation.start.copy()
        self._kb = None
