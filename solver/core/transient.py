r"""Implicit time stepping: backward Euler (default) or variable-step BDF2, with
error-controlled adaptive substeps.

The face is stiff (K/mu = 500) and strongly overdamped (alpha = 40 1/s and beta = 0.03 s
give every mode a damping ratio >= 1.1), so the integrator must be L-stable: both methods
are. For the step t_n -> t_{n+1} = t_n + h with u = u_{n+1} and w = h / h_{n-1}:

    v_{n+1} = (a0 u + a1 u_n + a2 u_{n-1}) / h,   a_{n+1} = (a0 v_{n+1} + a1 v_n + a2 v_{n-1}) / h
    BDF2: a0 = (1 + 2w)/(1 + w), a1 = -(1 + w), a2 = w^2/(1 + w);   backward Euler: 1, -1, 0

and M a + C v + f_int(u) = f_ext is solved by Newton (solver.core.newton). Both are the
form v = c (u - u_d), a = c^2 (u - u_m) with c = a0 / h (Stage; solver.core.terms.inertia).
BDF2 needs one substep of history (u_{n-1}, v_{n-1}, h_{n-1}), which the state carries
across caller steps (``history``); its first substep, with none, is a backward Euler one.
C = alpha M + beta K_n is built once per substep and held fixed within it: on the
predicted end state u_n + h v_n for BDF2, on the start state for backward Euler.

Substep control: the local error estimate (Milne's device) is the corrector minus an
explicit predictor of the same order, scaled by the ratio of their error constants,

    BDF2: est = (1 + w)/(2 + 3 w) (u - p),  p = u_n + h v_n + h^2 (u_{n-1} - u_n + h_{n-1} v_n)/h_{n-1}^2
    backward Euler: est = (u - u_n - h v_n) / 2

in the weighted max norm err = max_i |est_i| / (atol + rtol |u_i|); a substep is accepted
when err <= 1, and a PI controller proposes the next h, growing a step by at most 2
(variable-step BDF2 is zero-stable for w < 1 + sqrt 2). The nodes a contact pushes on and
the prescribed DOFs are left out of the estimate.

A caller's step [t0, t1] is split as needed and lands exactly on t1: what is left, when at
most STRETCH (1.3) times the proposal, is one substep (retried at the proposal where its
Newton fails); ``even_steps`` splits it into equal substeps. Loads ramp linearly from t0
to t1 (``hold="ramp"``) or jump at t0 (``hold="step"``). A substep whose Newton fails is
retried at h/4; after ``max_cutbacks`` in a row the caller's step fails and the model
goes back to its state at t0. Newton starts from the ``predictor`` ("velocity"
u_n + h v_n, default; "quadratic"; "none" u_n), the prescribed DOFs put on their targets
where it came within ON_PATH of them. Each caller step starts with a new factorization,
so that a step repeated from the same state (an FMU rollback) repeats exactly.

Derivation (error estimate, controller, contact nodes, substeps, predictor, Newton's key):
docs/method.md, section 'Transient analysis'.
"""

from dataclasses import dataclass, field

import numpy as np

from solver.core.errors import ParameterError
from solver.core.linsolve import single_threaded_blas
from solver.core.newton import newton
from solver.core.terms.inertia import Damping, Inertia
from solver.core.units import TISSUE_DENSITY

PREDICTORS = ("velocity", "quadratic", "none")
# A substep that would end within this factor of its proposal from the caller step's end
# is stretched to land there (module docstring).
STRETCH = 1.3
# The controller's largest growth of a substep over the last (variable-step BDF2 is
# zero-stable for ratios below 1 + sqrt 2).
GROWTH = 2.0
METHODS = ("bdf2", "backward_euler")


@dataclass
class StepStats:
    """What a caller's step took."""

    converged: bool = True
    substeps: int = 0
    newton_iterations: int = 0
    cutbacks: int = 0
    rejected: int = 0
    factorizations: int = 0
    h_min: float = np.inf
    h_max: float = 0.0
    reason: str = ""
    history: list = field(default_factory=list)     # (t, h, iterations) per accepted substep


@dataclass(frozen=True)
class Stage:
    """One substep as the inertia and damping terms see it: v = c (u - u_d) and
    a = c^2 (u - u_m) at the end state u; the damping matrix is built on u_g. c in 1/s,
    the points (3 n,) in mm."""

    c: float
    u_d: np.ndarray
    u_m: np.ndarray
    u_g: np.ndarray


def coefficients(h, h_prev):
    """(a0, a1, a2) of v_{n+1} = (a0 u_{n+1} + a1 u_n + a2 u_{n-1}) / h: BDF2 with the step
    ratio w = h / h_prev, or backward Euler (1, -1, 0) when h_prev is None."""
    if h_prev is None:
        return 1.0, -1.0, 0.0
    w = h / h_prev
    return (1.0 + 2.0 * w) / (1.0 + w), -(1.0 + w), w * w / (1.0 + w)


def growth(err, err_prev, order, pi=True):
    """The factor for the next substep's size from its error err (weighted norm, accepted
    at <= 1) and the last accepted one err_prev, for a method of that order: the PI
    controller (pi; else the elementary one, after a rejection), within [0.3, GROWTH]."""
    k = order + 1
    if err == 0.0:
        return GROWTH
    if not pi:
        return min(GROWTH, max(0.3, 0.9 * err ** (-1.0 / k)))
    return min(GROWTH, max(0.3, 0.9 * err ** (-0.7 / k) * err_prev ** (0.4 / k)))


ON_PATH = 0.1    # predicted prescribed DOFs within this fraction of their move: put on target


class Transient:
    """Time stepping of a solver.Model (or a FaceModel's model).

    density tonne/mm^3; alpha 1/s, beta s; inertia / damping: include the terms;
    method 'bdf2' | 'backward_euler'; tol: the error's absolute tolerance atol (mm), rtol:
    its relative one; max_substep, min_substep (s); hold 'ramp' | 'step'; fixed_step: if
    set, substeps of exactly that size (no error control; tests of order); predictor
    'velocity' | 'quadratic' | 'none' and even_steps: see the module docstring.
    """

    def __init__(self, model, density=TISSUE_DENSITY, alpha=40.0, beta=0.03, inertia=True,
                 damping=True, tol=1e-3, max_substep=5e-3, min_substep=1e-7, hold="ramp",
                 max_cutbacks=8, fixed_step=None, predictor="velocity", even_steps=False,
                 method="backward_euler", rtol=0.0):
        for name, v in (("density", density), ("alpha", alpha), ("beta", beta)):
            if not (np.isfinite(v) and v >= 0):
                raise ParameterError(f"{name} = {v!r} must be a finite number >= 0")
        if not (tol > 0 and rtol >= 0 and max_substep > 0
                and 0 < min_substep <= max_substep):
            raise ParameterError("need tol > 0, rtol >= 0 and 0 < min_substep <= max_substep")
        if hold not in ("ramp", "step"):
            raise ParameterError(f"hold = {hold!r} must be 'ramp' or 'step'")
        if predictor not in PREDICTORS:
            raise ParameterError(f"predictor = {predictor!r} must be one of {PREDICTORS}")
        if method not in METHODS:
            raise ParameterError(f"method = {method!r} must be one of {METHODS}")
        self.predictor, self.even_steps, self.method = predictor, even_steps, method
        self.model = model
        self.tol, self.rtol = tol, rtol
        self.max_substep, self.min_substep = max_substep, min_substep
        self.hold, self.max_cutbacks, self.fixed_step = hold, max_cutbacks, fixed_step
        self.step_terms = []
        mesh = model.mesh
        mass3 = None
        if inertia and density > 0:
            self.inertia = Inertia(mesh, density)
            mass3 = self.inertia.m3
            self.step_terms.append(self.inertia)
        else:
            self.inertia = None
        if damping and (alpha > 0 or beta > 0):
            mass3 = mass3 if mass3 is not None else np.repeat(
                Inertia(mesh, density).mass, 3)
            self.damping = Damping(mass3, alpha, beta, model.elasticity)
            self.step_terms.append(self.damping)
        else:
            self.damping = None
        if not self.step_terms:
            raise ParameterError("a transient analysis needs inertia or damping")
        for t in self.step_terms:
            model.add_term(t)
        self.t = 0.0
        self.v = np.zeros_like(model.u)
        self.h = min(max_substep, 1e-3)
        self.history = None            # BDF2: (u_{n-1}, v_{n-1}) (n, 3) and h_{n-1} (s)
        self.err_prev = 1.0            # the PI controller's last accepted error
        self.dissipated = 0.0          # mJ: sum over substeps of h v^T C v (never negative)

    @property
    def order(self):
        return 2 if self.method == "bdf2" else 1

    def energy(self):
        """(kinetic, stored) energy in mJ at the current state (stored: all potentials
        of the model's terms other than inertia and damping)."""
        kin = self.inertia.kinetic_energy(self.v) if self.inertia else 0.0
        sysm = self.model.system()
        others = [t for t in sysm.terms if t not in self.step_terms]
        from solver.core.assembly import Assembly
        asm = Assembly(sysm.pattern, False)
        st = sysm.state(self.model.u.ravel())
        for term, ids in zip(sysm.terms, sysm._ids):
            if term in others:
                term.assemble(st, asm, ids)
        return kin, asm.energy

    def _predict(self, u_n, v_n, h, prev):
        """Newton's start for the substep of size h from (u_n, v_n); prev: (u_{n-1},
        v_{n-1}, h_{n-1}), or None."""
        if self.predictor == "none":
            return u_n
        if self.predictor == "quadratic" and prev is not None:
            return u_n + h * (v_n + h * (v_n - prev[1]) / prev[2])
        return u_n + h * v_n

    def _stage(self, u_n, v_n, h, prev):
        """The Stage of the substep h from (u_n, v_n) with history prev (or None: backward
        Euler), and the error estimate's predictor and factor (module docstring)."""
        h_prev = prev[2] if prev is not None else None
        a0, a1, a2 = coefficients(h, h_prev)
        u_pred = u_n + h * v_n
        if h_prev is None:
            u_d, b_a = u_n, -v_n
            factor, p = 0.5, u_pred
        else:
            u_d = -(a1 * u_n + a2 * prev[0]) / a0
            b_a = a1 * v_n + a2 * prev[1]
            w = h / h_prev
            p = u_pred + (h / h_prev) ** 2 * (prev[0] - u_n + h_prev * v_n)
            factor = (1.0 + w) / (2.0 + 3.0 * w)
        c = a0 / h
        u_m = u_d - b_a / (a0 * c)
        u_g = u_n if self.method == "backward_euler" else u_pred
        return Stage(c, u_d, u_m, u_g), (a0, a1, a2), p, factor

    def _substep(self, sysm, u_n, v_n, h, targets, opts, prev=None, last=None):
        """Newton for the substep h from (u_n, v_n): prev, BDF2's history (None: backward
        Euler); last, the previous accepted substep (u, v, h) for the predictor (None at a
        backward Euler caller step's start). (u, v, error estimate, NewtonReport); u, v and
        the estimate None where Newton failed."""
        stage, coef, p, factor = self._stage(u_n, v_n, h, prev)
        for term in self.step_terms:
            term.prepare(stage)
        lin = self.model.linear_solver
        u0 = self._predict(u_n, v_n, h, last)
        if u0 is not u_n and len(targets):
            pres = sysm.prescribed
            jump = np.abs(targets - u0[pres]).max()
            if jump <= ON_PATH * np.abs(u0[pres] - u_n[pres]).max():
                u0[pres] = targets
        key = (float(f"{stage.c:.9e}"), self.damping.generation if self.damping else 0)
        u, _, rep = newton(sysm, u0, targets, lin, opts, key=key)
        if u is None and u0 is not u_n:
            u, _, rep2 = newton(sysm, u_n, targets, lin, opts, key=key)
            rep2.iterations += rep.iterations
            rep2.factorizations += rep.factorizations
            rep = rep2
        if u is None:
            return None, None, None, rep
        a0, a1, a2 = coef
        v = (a0 * u + a1 * u_n + (a2 * prev[0] if a2 else 0.0)) / h
        return u, v, factor * (u - p), rep

    def _size(self, h, t, t_end, h_last, stretch=True):
        """The next substep's size from the proposal h at t (module docstring); h_last
        when it is that size to rounding (a split's equal substeps keep one h, the key of
        Newton's factorization). stretch: whether the substep may take the rest of the
        step (not right after a rejection: the retry would be stretched back)."""
        span = t_end - t
        if self.fixed_step:
            return min(h, span)
        if stretch and span <= min(STRETCH * h, self.max_substep * (1.0 + 1e-9)):
            return span                 # the step's end in one substep: no sliver after it
        if not self.even_steps:
            return min(h, span)
        n = max(1, int(np.ceil(span / h * (1.0 - 1e-9))))
        h = span / n
        return h_last if h_last and abs(h - h_last) <= 1e-9 * h else h

    def _grow(self, err, rejected=False):
        """The factor for the next step size from the error err (weighted norm, accepted
        at <= 1; module docstring)."""
        return growth(err, self.err_prev, self.order,
                      pi=not rejected and self.method != "backward_euler")

    def advance(self, t_end):
        """Integrate from self.t to t_end (> self.t); returns StepStats. On failure the
        model, velocity, history and time stay at their values at the start of the call.
        BLAS runs on one thread meanwhile (solver.core.linsolve.single_threaded_blas)."""
        with single_threaded_blas():
            return self._advance(t_end)

    def _advance(self, t_end):
        t0 = self.t
        span = t_end - t0
        if not (np.isfinite(t_end) and span > 0):
            raise ParameterError(f"step end {t_end!r} must be after the current time {t0!r}")
        model = self.model
        sysm = model.system()
        opts = model.newton_options
        pres = sysm.prescribed
        p_target = np.array([model._target[d] for d in pres])
        u, v = model.u.ravel().copy(), self.v.ravel().copy()
        p_start = u[pres].copy()
        u0, v0, d0 = u.copy(), v.copy(), self.dissipated
        hist0, err0 = self.history, self.err_prev
        pattern0 = sysm.snapshot()
        touch = self._touching_at(sysm, u)                 # at u_n, from u_n alone
        stats = StepStats()
        t, run, retry = t0, 0, False
        prev = None                     # BDF2's history: (u, v, h) one substep back
        if self.method == "bdf2" and self.history is not None:
            prev = (self.history[0].ravel(), self.history[1].ravel(), self.history[2])
        last = prev                     # the predictor's: this caller step's, or BDF2's
        model.linear_solver.invalidate()
        h_prop = self.fixed_step or min(self.h, self.max_substep)
        h_last = None
        while t < t_end - 1e-12 * max(1.0, abs(t_end)):
            h = self._size(h_prop, t, t_end, h_last, stretch=not retry)
            t_new = t + h
            if t_end - t_new < 1e-9 * span:
                t_new, h = t_end, t_end - t
            lam = 1.0 if self.hold == "step" else (t_new - t0) / span
            sysm.lam, sysm.t = lam, t_new
            targets = model.path_targets(pres, p_start, p_target, lam)
            u_new, v_new, est, rep = self._substep(sysm, u, v, h, targets, opts, prev, last)
            stats.newton_iterations += rep.iterations
            stats.factorizations += rep.factorizations
            if u_new is None and h > h_prop * (1.0 + 1e-9):
                stats.rejected += 1     # a stretched substep: retried at the proposal
                retry = True
                continue
            if u_new is None:
                stats.cutbacks += 1
                run += 1
                if run > self.max_cutbacks or h / 4 < self.min_substep:
                    stats.converged = False
                    stats.reason = f"at t = {t_new:.6g} s: {rep.reason}"
                    model.u = u0.reshape(-1, 3)
                    self.v = v0.reshape(-1, 3)
                    self.dissipated = d0
                    self.history, self.err_prev = hist0, err0
                    sysm.lam = 0.0
                    sysm.restore(u0, pattern0)
                    return stats
                h_prop, retry = h / 4, True
                continue
            run, retry = 0, False
            touch_new = self._touching(sysm)
            est[pres] = 0.0             # prescribed DOFs are exact: no error of the method
            err = self._error(est, u_new, self.tol, self.rtol, touch, touch_new)
            if self.fixed_step is None and err > 1.0 and h > self.min_substep * 1.0001:
                stats.rejected += 1
                retry = True
                h_prop = max(h * self._grow(err, rejected=True), self.min_substep)
                continue
            if self.damping is not None:
                self.dissipated += h * float(v_new.ravel() @ self.damping.force(v_new))
            last = (u, v, h)
            if self.method == "bdf2":
                prev = last
            h_last = h
            u, v, t, touch = u_new, v_new, t_new, touch_new
            sysm.commit(u)
            stats.substeps += 1
            stats.h_min, stats.h_max = min(stats.h_min, h), max(stats.h_max, h)
            stats.history.append((t, h, rep.iterations))
            if self.fixed_step is None:
                grow = self._grow(err)
                self.err_prev = max(err, 1e-4)
                landed = h < h_prop and grow >= 1.0
                h_prop = min(max(h * grow, h_prop) if landed else h * grow, self.max_substep)
                self.h = h_prop
        self.t = t_end
        model.u = u.reshape(-1, 3).copy()
        self.v = v.reshape(-1, 3).copy()
        self.history = None if prev is None else (
            prev[0].reshape(-1, 3).copy(), prev[1].reshape(-1, 3).copy(), float(prev[2]))
        return stats

    @classmethod
    def _touching_at(cls, sysm, u):
        """(n,) bool: the nodes the nonsmooth terms push on at u (ndof,), evaluated there
        (not carried over from the last step: a step from a state set by set_state then
        repeats exactly), or None without such terms."""
        if not any(t.nonsmooth for t in sysm.terms):
            return None
        sysm.nonsmooth_residual(u)
        return cls._touching(sysm)

    @staticmethod
    def _touching(sysm):
        """(n,) bool: the nodes the nonsmooth terms pushed on at their last evaluation (the
        converged state after Newton), or None without such terms."""
        parts = [t.touching() for t in sysm.terms if t.nonsmooth]
        return np.logical_or.reduce(parts) if parts else None

    @staticmethod
    def _error(est, u, atol, rtol, touch, touch_new):
        """The weighted max norm max_i |est_i| / (atol + rtol |u_i|) of a substep's error
        estimate est (3 n,) at its end state u (3 n,; mm), over the nodes no contact pushed
        on at either end (touch, touch_new: (n,) bool at its start and end, or None where
        unknown: then over all nodes). Accepted at <= 1."""
        a = (np.abs(est) / (atol + rtol * np.abs(u))).reshape(-1, 3).max(axis=1)
        if touch is not None and touch_new is not None:
            a = a[~(touch | touch_new)]
        return float(a.max(initial=0.0))


@dataclass
class RelaxResult:
    """What a damped relaxation to a static equilibrium took: converged; pseudo_time (s)
    of damped motion; substeps and Newton iterations (the relaxation's and the final
    undamped Newton's); reason (why it failed, if it did)."""

    converged: bool = False
    pseudo_time: float = 0.0
    substeps: int = 0
    newton_iterations: int = 0
    reason: str = ""


def relax(model, alpha=40.0, beta=0.03, ramp=0.1, chunk=0.1, t_max=2.0, tol=0.01,
          max_substep=0.02):
    r"""Static equilibrium by damped pseudo-time: the loads ramp to their targets over
    ``ramp`` (s) under Rayleigh damping alone (no inertia),

        C (u - u_n) / h + f_int(u) = f_ext(lam(t)),    C = alpha M + beta K_n,

    and the damped motion continues in ``chunk``-long spans until an undamped Newton from
    its state converges (then the result is a static equilibrium to Newton's own
    tolerance, not an approximate one) or until ``t_max`` of pseudo-time has passed.

    Why: load-stepped Newton follows one branch of equilibria and stops where the
    tangent turns singular (a limit point: the compressed lip ring under full OOP
    folds) or where contact's active set cycles between iterates. Damped motion passes
    both, to the equilibrium the damped face settles into, as the transient analysis
    does; a load with no stable equilibrium keeps it moving and fails after t_max. With
    the paper's alpha = 40 1/s and beta = 0.03 s every mode is overdamped (damping ratio
    >= 1.1, above), so the slowest relaxes within a few tenths of a second.

    The model must hold no inertia or damping term of its own (a static model). On
    failure the model is back at its state before the call (u, load factor, contact
    blocks); the caller restores its load targets. Returns a RelaxResult.
    """
    sysm = model.system()
    u_start = model.u.ravel().copy()
    lam_start = sysm.lam
    pattern_start = sysm.snapshot()
    tr = Transient(model, alpha=alpha, beta=beta, inertia=False, damping=True, tol=tol,
                   max_substep=max_substep, hold="ramp", method="backward_euler")
    res = RelaxResult()
    try:
        t_next = ramp
        while True:
            stats = tr.advance(t_next)
            res.substeps += stats.substeps
            res.newton_iterations += stats.newton_iterations
            if not stats.converged:
                res.reason = f"damped relaxation failed {stats.reason}"
                break
            res.pseudo_time = tr.t
            for term in tr.step_terms:
                model.remove_term(term)
            sysm = model.system()
            sysm.lam = 1.0
            pres = sysm.prescribed
            targets = np.array([model._target[d] for d in pres])
            model.linear_solver.invalidate()
            u, _, rep = newton(sysm, model.u.ravel().copy(), targets, model.linear_solver,
                               model.newton_options)
            res.newton_iterations += rep.iterations
            if u is not None:
                sysm.commit(u)
                model.u = u.reshape(-1, 3).copy()
                res.converged = True
                return res
            if tr.t >= t_max - 1e-12:
                res.reason = (f"no static equilibrium within {t_max:g} s of damped "
                              f"pseudo-time: the undamped Newton from the relaxed state "
                              f"failed ({rep.reason})")
                break
            for term in tr.step_terms:
                model.add_term(term)
            model.system().restore(model.u.ravel())
            tr.hold = "step"            # the loads are at their targets: lam = 1 from now on
            t_next = min(tr.t + chunk, t_max)
    finally:
        for term in tr.step_terms:
            if term in model.terms:
                model.remove_term(term)
    sysm = model.system()
    model.u = u_start.reshape(-1, 3).copy()
    sysm.lam = lam_start
    sysm.restore(u_start, pattern_start)
    return res
