r"""`open_simulation(scene, fidelity="realtime")`: the reduced model behind Simulation's API.

The full-order Simulation of the scene is built as usual (coarse generic half face, loose
tolerances: solver.app.fidelity.REDUCED["realtime"]): it provides the anatomy, terms, activations and lip
outputs, and it is the fallback. Its reduced model (solver.rom.store) is looked up by the
scene's key in the folders `rom_dirs` (e.g. the resources of an FMU built with
`python build_fmu.py --rom`), then in the user cache, then among the models that ship
with the project (solver/rom/models); where there is none,
ModelNotTrained names the training command. Its knobs are one ReducedOptions.

Time stepping (solver.rom.stepper): variable-step BDF2 in reduced coordinates at
error-controlled substeps of at most h = 5 ms (tol, mm), or backward Euler at fixed
substeps of at most 1 ms (integrator "backward_euler"), activations ramping within a
caller's step as in the full model (hold "ramp"); modified Newton with a frozen reduced
tangent on solver.rom.online, converged when |dq| <= utol (mm; default 1e-2). Damping
C = alpha M + beta K_n with K_n hyper-reduced by the cubature (damping="current",
default), or the constant V^T K_0 V (damping="rest").

The jaw: u = V q + L(p), the lifting L of the jaw's pose p (solver.rom.lifting), ramping
within a step as in the full model. A target pose outside the poses the model's
snapshots covered (meta "jaw_envelope"): a TrustWarning naming it, and the full model
from then on (trust "fallback").

Trust check (solver.rom.trust): every `check_every` substeps, rho = |R_free(V q)| / scale,
the full-order residual of u = V q + L on the free DOFs (with inertia and damping) over
the force scale max(|f_tissue|, |f_cables|, 1e-3 N), against the model's trust threshold;
after every step, the contact's deepest penetration against
solver.face.terms.contact.TOLERANCE. trust="fallback" (default): a warning, the caller's
step is redone by the full model from the reduced state at its start, and the simulation
stays full-order from then on (`mode` = "full"); "warn": a warning the first time for
each cause (penetration, residual), every such step counted in `trust_exceeded` {cause:
steps}; "off": no check. A substep that fails after every split also falls back (or
fails, with trust "warn"/"off").

Why these defaults, and what the trust check measures: docs/method.md, sections 'Reduced
time stepping' and 'Trust check and fallback'.
"""

import warnings
from dataclasses import dataclass, fields, replace

import numpy as np

from solver.core.errors import ParameterError
from solver.core.linsolve import single_threaded_blas
from solver.app.fidelity import REDUCED, apply_fidelity
from solver.app.simulation import SceneDriver, Simulation, resolve_scene
from solver.core.transient import StepStats
from solver.core.units import kg_per_m3
from solver.face.jaw import JAW_INPUTS, JAW_UNITS
from solver.face.terms.contact import TOLERANCE
from solver.rom.reduced import ReducedOperator
from solver.rom.stepper import H_MAX, H_MAX_BE, INTEGRATORS, Stepper
from solver.rom.store import find_model, load_model
from solver.rom.outputs import LipOutputs
from solver.rom.trust import TrustCheck

TRUST_MODES = ("fallback", "warn", "off")
TRUST_CAUSES = ("failed", "penetration", "residual")   # keys of trust_exceeded


class TrustWarning(UserWarning):
    """The reduced solution left the range the model was trained on."""


@dataclass(frozen=True)
class ReducedOptions:
    """The reduced model's knobs. trust: 'fallback' | 'warn' | 'off'; check_every:
    substeps between trust checks; integrator 'bdf2' | 'backward_euler'; tol: the
    substeps' absolute error tolerance (mm; None: fixed substeps of h; backward Euler
    takes none); h: largest substep (s; None: H_MAX (BDF2) or H_MAX_BE (backward Euler),
    or the scene's max_substep where that is smaller); utol (mm), max_iter, rate,
    contact_delta, max_frozen, kb_every: the reduced Newton's (solver.rom.stepper);
    damping 'rest' (C_r constant) or 'current' (K_n by the cubature on the substep's
    shape); warmup: load every kernel at construction (ReducedSimulation.warmup)."""

    trust: str = "fallback"
    check_every: int = 20
    integrator: str = "bdf2"
    tol: float | None = 0.1
    h: float | None = None
    utol: float = 1e-2
    max_iter: int = 20
    damping: str = "current"
    rate: float = 0.8
    contact_delta: float = 0.5
    max_frozen: int = 6
    kb_every: int = 50
    warmup: bool = True

    def __post_init__(self):
        if self.damping not in ("rest", "current"):
            raise ParameterError(f"damping = {self.damping!r} is not 'rest' or 'current'")
        if self.trust not in TRUST_MODES:
            raise ParameterError(f"trust = {self.trust!r} is not one of {TRUST_MODES}")
        if self.integrator not in INTEGRATORS:
            raise ParameterError(f"integrator = {self.integrator!r} is not one of "
                                 f"{INTEGRATORS}")
        if self.tol is not None and not (isinstance(self.tol, (int, float)) and self.tol > 0):
            raise ParameterError(f"tol = {self.tol!r} must be a number > 0 (mm) or None")


OPTION_NAMES = frozenset(f.name for f in fields(ReducedOptions))


class ReducedSimulation(SceneDriver):
    """The reduced model of a scene behind Simulation's API. It holds the scene's
    full-order Simulation (``full``): its face, anatomy, scene and contact terms are the
    reduced model's, its set_inputs checks the inputs, and it takes over from the reduced
    state where the trust check fails (``mode`` "full"). rom_model: a .npz path or an
    (arrays, meta) pair (this model whatever the scene's key); rom_dirs: folders searched
    for the scene's model before the user cache (e.g. an FMU's resources); options: a
    ReducedOptions, whose fields may also be given as keywords (they replace its values);
    the other keywords go to the full-order Simulation."""

    def __init__(self, scene="default", loaded_anatomy=None, fidelity=None,
                 rom_model=None, rom_dirs=(), options=None, **overrides):
        knobs = {k: overrides.pop(k) for k in list(overrides) if k in OPTION_NAMES}
        opts = replace(options or ReducedOptions(), **knobs)
        self.options = opts
        trust, check_every, h, utol, max_iter = (opts.trust, opts.check_every, opts.h,
                                                 opts.utol, opts.max_iter)
        scene = resolve_scene(scene)
        if fidelity is None and scene.fidelity not in REDUCED:
            fidelity = "realtime"
        if fidelity is not None and fidelity != scene.fidelity:
            scene = apply_fidelity(scene, fidelity)   # else a scene (file) that names it:
                                                      # its knobs, its own keys winning
        self.full = full = Simulation(scene, loaded_anatomy, **overrides)
        self.scene, self.anatomy, self.face = full.scene, full.anatomy, full.face
        self.contact = full.contact
        self.mode = "rom"
        self._t, self._last = 0.0, StepStats()
        sc = self.scene
        if sc.analysis != "transient" or sc.gravity != "none" or not (sc.inertia or sc.damping):
            raise ParameterError("fidelity 'realtime' runs transient scenes without gravity "
                                 f"(scene {sc.name!r}: analysis {sc.analysis!r}, gravity "
                                 f"{sc.gravity!r}); use fidelity 'fast'")
        if rom_model is None:
            arrays, meta = find_model(sc, rom_dirs)
        elif isinstance(rom_model, tuple):
            arrays, meta = rom_model
        else:
            arrays, meta = load_model(rom_model)
        self.rom_meta = meta
        self.trust, self.check_every = trust, int(check_every)
        bdf2 = opts.integrator == "bdf2"
        h = min(H_MAX if bdf2 else H_MAX_BE, sc.max_substep) if h is None else h
        self.h_max, self.utol, self.max_iter = h, utol, max_iter
        self.trust_threshold = float(arrays["trust_threshold"][0])
        V = arrays["V"]
        alpha = sc.alpha if sc.damping else 0.0
        beta = sc.beta if sc.damping else 0.0
        m_scale = 1.0 if sc.inertia else 0.0
        M_r = arrays["M_r"]
        self.op = ReducedOperator(full, V, arrays["bricks"], arrays["weights"],
                                  m_scale * M_r, alpha * M_r + beta * arrays["K0_r"])
        self.stepper = Stepper(self.op, M_r, alpha, beta, opts.damping, h, utol, max_iter,
                               opts.rate, opts.contact_delta, opts.max_frozen, opts.kb_every,
                               opts.integrator, opts.tol if bdf2 else None)
        r = V.shape[1]
        self.q, self.v_r = np.zeros(r), np.zeros(r)
        self._substeps = 0
        self.checker = None if trust == "off" else \
            TrustCheck(full, kg_per_m3(sc.density), alpha, beta, m_scale, opts.damping)
        self._outputs = LipOutputs(self.face, V)
        self.fallbacks = 0               # handovers to the full model (_to_full)
        self.full_time = 0.0             # s of simulated time the full model has run
        self.trust_exceeded = {}         # trust "warn": {cause: steps past its limit}
        self.trust_history = []          # (t, rho) of every check
        if opts.warmup:
            self.warmup()

    def warmup(self):
        """Run one substep from the current state and a trust check, then restore the
        state: numba compiles (or loads from its cache) every kernel of the online step at
        its first call, which would otherwise fall on the first steps of a run."""
        state = self.get_state()
        self.stepper.advance(self.q, self.v_r, self.face.activation, self.t,
                             self.t + self.h_max, StepStats(), self.face.jaw)
        if self.checker is not None:
            self.checker.residual(self.op.V, self.q, self.q, self.v_r, self.h_max)
        self.set_state(state)

    def _lift(self):
        """(n, 3) the lifting at the jaw's committed pose (zeros without a jaw)."""
        jaw = self.face.jaw
        return self.op.lifting.at(None if jaw is None else jaw.start)[0]

    def trust_residual(self):
        """rho (solver.rom.trust) at the current reduced state (after a substep)."""
        if self.checker is None:
            sc = self.scene
            self.checker = TrustCheck(self.full, kg_per_m3(sc.density), self.stepper.alpha,
                                      self.stepper.beta, 1.0 if sc.inertia else 0.0,
                                      self.stepper.damping)
        q_n, v_n, h, stage = self.stepper.last
        return self.checker.residual(self.op.V, self.q, q_n, v_n, h, self.op.L, self.op.L_n,
                                     stage)

    # -- what the held full-order Simulation answers --------------------------------------
    @property
    def t(self):
        """s: the current time (the full model's once it took over)."""
        return self.full.t if self.mode == "full" else self._t

    @t.setter
    def t(self, value):
        self._t = self.full.t = float(value)

    @property
    def last(self):
        """StepStats of the last step."""
        return self.full.last if self.mode == "full" else self._last

    @last.setter
    def last(self, stats):
        self._last = stats

    @property
    def integrator(self):
        """The full model's transient integrator (its energy bookkeeping, the fallback)."""
        return self.full.integrator

    @property
    def term_names(self):
        return self.full.term_names

    @property
    def jaw(self):
        return self.full.jaw

    def release(self):
        self.full.release()

    def _to_full(self, q, v):
        """Hand the reduced state to the full model (from then on, mode 'full')."""
        L = self._lift()
        self.face.model.u = self.op.displacement(q, L).copy()
        self.integrator.v = self.op.displacement(v, 0.0 * L).copy()
        self.integrator.t = self.full.t = self._t
        self.face.model.system().restore(self.face.model.u.ravel())   # contact candidates
        self.mode = "full"
        self.fallbacks += 1

    def _full_step(self, t_end):
        """The full model's step to t_end, its simulated time counted in full_time."""
        t0 = self.full.t
        stats = self.full.step(t_end)
        if stats.converged:
            self.full_time += float(t_end) - t0
        return stats

    def step(self, t_end):
        """Advance to t_end; StepStats (converged False leaves the state at its start)."""
        if self.mode == "full":
            return self._full_step(t_end)
        if not (np.isfinite(t_end) and t_end > self.t):
            raise ParameterError(f"step end {t_end!r} must be after the current time "
                                 f"{self.t!r}")
        act, jaw = self.face.activation, self.face.jaw
        start = (self.q, self.v_r, self._substeps)
        stats = StepStats()
        with single_threaded_blas():    # r-sized products: threads cost more than they give
            ok, q, v = self.stepper.advance(self.q, self.v_r, act, self.t, t_end, stats, jaw)
        if ok:
            self.q, self.v_r = q, v
            self._substeps += stats.substeps
        rho = None
        if ok and self.trust != "off" and self._substeps // self.check_every \
                > start[2] // self.check_every:
            rho = self.trust_residual()
            self.trust_history.append((float(t_end), rho))
        pen = self.stepper.penetration if ok and self.trust != "off" else 0.0
        bad = not ok or (rho is not None and rho > self.trust_threshold) or pen > TOLERANCE
        if bad:
            cause = "failed" if not ok else "penetration" if pen > TOLERANCE else "residual"
            what = (f"reduced step failed ({stats.reason})" if not ok else
                    f"contact penetration {pen:.3g} mm above the contact tolerance "
                    f"{TOLERANCE} mm" if pen > TOLERANCE else
                    f"full-order residual of the reduced state {rho:.3g} (relative) above "
                    f"the trust threshold {self.trust_threshold:.3g}")
            if self.trust == "fallback":
                warnings.warn(f"realtime model at t = {t_end:.4g} s: {what}; switching to "
                              "the full model", TrustWarning, stacklevel=2)
                self.q, self.v_r, self._substeps = start
                self._to_full(start[0], start[1])
                stats = self._full_step(t_end)
                stats.reason = (stats.reason + "; " if stats.reason else "") + \
                    "fell back to the full model"
                return stats
            if not ok:
                self.face.end_step(False)                   # the inputs' targets back
                stats.converged = False
                self.last = stats
                return stats
            self.trust_exceeded[cause] = self.trust_exceeded.get(cause, 0) + 1
            if self.trust_exceeded[cause] == 1:
                warnings.warn(f"realtime model at t = {t_end:.4g} s: {what} (trust 'warn': "
                              f"further steps past it are counted in trust_exceeded, not "
                              f"warned)", TrustWarning, stacklevel=2)
        self.face.end_step(True)                            # the inputs committed
        self.t = float(t_end)
        self.last = stats
        return stats

    def set_inputs(self, activations=None, jaw=None, undriven="error"):
        """As Simulation.set_inputs (the full model checks them). A target jaw pose outside
        the poses the model was trained on (meta "jaw_envelope") is outside its envelope:
        the simulation goes on with the full model (mode 'full', a TrustWarning naming the
        input and the envelope)."""
        idle = self.full.set_inputs(activations, jaw, undriven)    # checked, or refused
        if jaw is not None and self.face.jaw is not None:
            self._check_envelope()
        return idle

    def _check_envelope(self):
        """The jaw's target against the training envelope (set_inputs)."""
        if self.mode != "rom" or self.trust == "off":
            return
        envelope = self.rom_meta.get("jaw_envelope", {})
        for name, value in zip(JAW_INPUTS, self.face.jaw.target):
            lo, hi = envelope.get(name, (0.0, 0.0))
            if not lo - 1e-9 <= value <= hi + 1e-9:
                warnings.warn(f"realtime model at t = {self.t:.4g} s: {name} = {value:g} "
                              f"{JAW_UNITS[name]} is outside its training envelope "
                              f"[{lo:g}, {hi:g}]; switching to the full model",
                              TrustWarning, stacklevel=4)
                if self.trust == "fallback":
                    self._to_full(self.q, self.v_r)
                return

    # -- outputs and state ---------------------------------------------------------------
    def outputs(self):
        if self.mode == "full":
            return {**self.full.outputs(), "rom_fallbacks": self.fallbacks,
                    "rom_full_time": self.full_time}
        L = self._lift()
        if "muscle_strains" in self.scene.record:
            u = self.op.displacement(self.q, L)
            out = self.face.lip_outputs(u)
            for m, (lo, hi) in self.face.region_strains(u).items():
                out[f"strain_min_{m}"], out[f"strain_max_{m}"] = lo, hi
        else:
            out = self._outputs(self.q, L)
        out["incisor_opening"] = self.face.incisor_opening()
        out["contact_force"] = self.stepper.contact_force
        out["newton_iterations"] = self.last.newton_iterations
        out["substeps"] = self.last.substeps
        out["cutbacks"] = self.last.cutbacks
        out["rom_fallbacks"] = self.fallbacks
        out["rom_full_time"] = self.full_time
        return out

    @property
    def u(self):
        """(n, 3) the current displacements (reconstructed in mode 'rom')."""
        return self.face.u if self.mode == "full" else self.op.displacement(self.q,
                                                                             self._lift())

    def _exceeded(self):
        """trust_exceeded as an array (TRUST_CAUSES order), for a state that serializes."""
        return np.array([self.trust_exceeded.get(c, 0) for c in TRUST_CAUSES], dtype=np.int64)

    @property
    def v(self):
        """(n, 3) the current velocities (mm/s; V v_r in mode 'rom')."""
        return self.full.v if self.mode == "full" else self.op.displacement(self.v_r, 0.0)

    def get_state(self, fresh=True):
        if self.mode == "full":
            return {**self.full.get_state(fresh), "mode": "full", "fallbacks": self.fallbacks,
                    "full_time": self.full_time,
                    "trust_exceeded": self._exceeded()}
        if fresh:
            self.stepper.reset_caches()      # the next step starts afresh, as after set_state
        L = self._lift()
        return {"t": self.t, "u": self.op.displacement(self.q, L).copy(),
                "v": self.v.copy(),
                "activation": self.face.activation.start.copy(), "jaw": np.array(self.jaw),
                "h": self.stepper.h, "err_prev": self.stepper.err_prev,
                "fallbacks": self.fallbacks, "full_time": self.full_time,
                "trust_exceeded": self._exceeded(),
                "q": self.q.copy(), "v_r": self.v_r.copy(), "mode": "rom",
                **self._history_state()}

    def _history_state(self):
        """The stepper's BDF2 history as plain arrays: q_prev, v_prev (r,; empty: none),
        h_prev (s; 0: none) and the lifting one substep back (L_prev (n, 3); empty when
        it is the current one: the jaw did not move)."""
        hist = self.stepper.history
        if hist is None:
            return {"q_prev": np.zeros(0), "v_prev": np.zeros(0), "h_prev": 0.0,
                    "L_prev": np.zeros((0, 3))}
        same = hist[3] is self.op.L or np.array_equal(hist[3], self._lift())
        return {"q_prev": hist[0].copy(), "v_prev": hist[1].copy(), "h_prev": float(hist[2]),
                "L_prev": np.zeros((0, 3)) if same else np.array(hist[3])}

    def set_state(self, state):
        self.fallbacks = int(state.get("fallbacks", self.fallbacks))
        self.full_time = float(state.get("full_time", self.full_time))
        if "trust_exceeded" in state:
            counts = np.asarray(state["trust_exceeded"], dtype=np.int64).ravel()
            self.trust_exceeded = {c: int(n) for c, n in zip(TRUST_CAUSES, counts) if n}
        if state.get("mode", "rom") == "full":
            self.mode = "full"
            self.full.set_state(state)
            return
        self.mode = "rom"
        self.t = float(state["t"])
        self.face.set_jaw_state(state.get("jaw", (0.0, 0.0)))     # the lifting below
        V = self.op.V
        self.q = np.array(state["q"], float) if "q" in state else \
            V.T @ (np.asarray(state["u"], float).ravel() - self._lift().ravel())
        self.v_r = np.array(state["v_r"], float) if "v_r" in state else \
            V.T @ np.asarray(state["v"], float).ravel()
        self.face.restore_inputs(state["activation"], state.get("jaw", (0.0, 0.0)))
        st = self.stepper
        if "h" in state:
            st.h = float(state["h"])
        st.err_prev = float(state.get("err_prev", 1.0))
        h_prev = float(state.get("h_prev", 0.0))
        if h_prev > 0.0:
            # none stored: the lifting one substep back was the restored pose's
            L_prev = np.asarray(state.get("L_prev", np.zeros((0, 3))), float)
            st.history = (np.array(state["q_prev"], float), np.array(state["v_prev"], float),
                          h_prev, self._lift() if not L_prev.size else L_prev.reshape(-1, 3))
        else:
            st.history = None
        st.reset_caches()
