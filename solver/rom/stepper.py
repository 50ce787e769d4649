"""Reduced time stepping: variable-step BDF2 (default) or backward Euler in q.

With v = c (q - q_d) and a = c^2 (q - q_m) at a substep's end (the full model's form and
coefficients, solver.core.transient; backward Euler c = 1 / h, q_d = q_n, q_m = q_n +
h v_n), each substep solves

    R(q) = c^2 M_r (q - q_m) + c C (q - q_d) + f(q, a) = 0,

activations and the jaw's pose ramping within a caller's step as in the full model (the
jaw's lifting L(p) at the substep's end and start, solver.rom.lifting; its history point
L_d as q_d). BDF2 steps under the full model's error control: Milne's estimate on the
displacements V est (the lifting is exact), largest nodal norm against tol (mm), a PI
controller, substeps of at most h_max landing on the caller's step (STRETCH). Without
tol, fixed substeps of h_max. A substep whose Newton fails is retried at a quarter of its
size, twice at most. Damping C_r = alpha M_r + beta V^T K_n V, K_n the passive
small-strain stiffness by the cubature on the predicted end shape (BDF2; backward Euler:
the start shape) with damping "current", or the constant rest one with "rest".

Newton: modified Newton on solver.rom.online.OnlineOperator. The damping force is
evaluated matrix-free at every iteration (exact); the tangent J = c^2 M_r + c alpha M_r
+ c beta K_n + K_bricks + K_switch is kept, LU-factorized, across iterations and
substeps, and refreshed when an iteration converges slowly (rate, max_frozen: first
K_switch, then K_n and K_bricks, rebuilt on the current shape when older than kb_every
substeps). J changes the path, not the root. Newton starts from BDF2's predictor
(backward Euler: q_n + h v_n + h^2 a_n). Converged when |dq| <= utol and theta / (1 -
theta) |dq| <= utol, theta the observed contraction. tests/rom_reference.py holds the
reference it is tested against: the general kernels, the contact terms' own assemble()
and full Newton, in backward Euler steps.

utol in mm: V is orthonormal, so |dq| is the Euclidean norm of the displacement
correction. The caches (tangents, predictor, contact lists) change the path, not the
root; reset_caches() (called by the simulation's get_state and set_state) makes a step
repeated from a restored state give the same answer bit for bit. Refresh rules and
stopping test: docs/method.md, section 'Reduced time stepping'.
"""

import math

import numpy as np
import scipy.linalg as sla

from solver.core.errors import ParameterError
from solver.core.transient import STRETCH, coefficients, growth
from solver.rom.online import OnlineOperator
from solver.rom.online_kernels import lu_solve_small

INTEGRATORS = ("bdf2", "backward_euler")
H_MAX = 5e-3        # s: the largest BDF2 substep, unless the scene asks for a smaller one
H_MAX_BE = 1e-3     # s: backward Euler's fixed substep
MAX_SPLITS = 2      # quarterings of a substep whose Newton fails, in a row


class StageR:
    """One reduced substep: c (1/s), q_d, q_m (r,) and the lifting's history point L_d
    (n, 3) of v = c (q - q_d), a = c^2 (q - q_m); the BDF2 coefficients (a0, a1, a2); the
    error estimate's predictor p (r,) and factor."""

    def __init__(self, q_n, v_n, h, prev, L_n):
        h_prev = prev[2] if prev is not None else None
        a0, a1, a2 = coefficients(h, h_prev)
        self.coef, self.h = (a0, a1, a2), h
        self.c = a0 / h
        pred = q_n + h * v_n
        if prev is None:
            self.q_d, b_a, self.factor, self.p = q_n, -v_n, 0.5, pred
            self.L_d = L_n
        else:
            w = h / h_prev
            self.q_d = -(a1 * q_n + a2 * prev[0]) / a0
            b_a = a1 * v_n + a2 * prev[1]
            self.p = pred + w * w * (prev[0] - q_n + h_prev * v_n)
            self.factor = (1.0 + w) / (2.0 + 3.0 * w)
            self.L_d = L_n if prev[3] is L_n else L_n + (a2 / a0) * (L_n - prev[3])
        self.q_m = self.q_d - b_a / (a0 * self.c)

    def velocity(self, q, q_n, prev):
        a0, a1, a2 = self.coef
        return (a0 * q + a1 * q_n + (a2 * prev[0] if a2 else 0.0)) / self.h


class Stepper:
    """op: solver.rom.reduced.ReducedOperator (its M_r: the inertia, zero without it, and
    its C_r: the damping, updated here); M_r (r, r) the reduced mass (for alpha M_r);
    alpha, beta: damping constants (0 without damping); damping: 'rest' | 'current';
    integrator 'bdf2' | 'backward_euler'; tol: the substeps' absolute error tolerance (mm;
    None: fixed substeps of h_max). The integrator's history (BDF2: the state one substep
    back), its proposal ``h`` and last error ``err_prev`` are state (get_state), not caches."""

    def __init__(self, op, M_r, alpha, beta, damping="current", h_max=H_MAX, utol=1e-4,
                 max_iter=20, rate=0.8, contact_delta=0.2, max_frozen=6, kb_every=50,
                 integrator="bdf2", tol=None):
        if integrator not in INTEGRATORS:
            raise ParameterError(f"integrator = {integrator!r} is not one of {INTEGRATORS}")
        if tol is not None and not tol > 0:
            raise ParameterError(f"tol = {tol!r} must be a number > 0 (mm) or None")
        self.integrator, self.tol = integrator, tol
        self.order = 2 if integrator == "bdf2" else 1
        self.history = None                     # (q_{n-1}, v_{n-1}, h_{n-1}, L_{n-1})
        self.h, self.err_prev = h_max, 1.0      # the controller's proposal, last error
        self.op, self.M_r, self.alpha, self.beta = op, op.M_r, alpha, beta
        self.M_damp = M_r
        self.damping = damping
        self.h_max, self.utol, self.max_iter = h_max, utol, max_iter
        self.rate, self.max_frozen, self.kb_every = rate, max_frozen, kb_every
        self.grow = 10.0                        # residual growth that triggers a backtrack
        self.online = OnlineOperator(op, contact_delta)
        self._current = damping == "current" and bool(beta)
        self.C_r = op.C_r
        self.last = None                        # (q_n, v_n, h, StageR) of the last substep
        self.stats = {"brick_tangents": 0, "switch_tangents": 0, "factorizations": 0,
                      "damping_builds": 0, "backtracks": 0, "slow": 0}
        self.reset_caches()

    def reset_caches(self):
        self._Kb = self._Ks = self._Kn = self._lu = self._a_kb = None
        self._Kparts = [None] * (self.online.parts if self.online is not None else 0)
        self._sets, self._A_key, self._bd = None, None, 0.0
        self._theta = 0.5
        self._a_prev = None
        self._kb_age = 0
        if self.online is not None:
            self.online.a = None
            self.online.contact.reset()

    @property
    def penetration(self):
        """The deepest contact penetration (mm) of the last force evaluation."""
        return self.online.contact.penetration

    @property
    def contact_force(self):
        return self.online.contact_force

    def _before_substep(self, q_n):
        """A hook at each substep's start, from its start state q_n (nothing here)."""

    # -- substeps -------------------------------------------------------------------------
    def advance(self, q, v, act, t0, t_end, stats, jaw=None):
        """Substeps from (q, v) at t0 to t_end (activations act: solver.face.activation,
        and the pose of jaw (solver.face.jaw.Jaw or None), ramping over the step); (ok, q,
        v). stats: a StepStats to fill. On failure the history and the controller stay
        as they were."""
        span = t_end - t0
        newton = self._newton
        adaptive = self.tol is not None
        prev = self.history if self.integrator == "bdf2" else None
        h_prop = min(self.h, self.h_max) if adaptive else self.h_max
        err_prev = self.err_prev
        t, lam_prev, run, retry = t0, 0.0, 0, False
        # fixed substeps: equal pieces of the step (fractions of it), a failed one split in
        # four in place (MAX_SPLITS deep)
        pieces = None if adaptive else \
            [(k + 1) / n for n in [max(1, int(math.ceil(span / self.h_max * (1 - 1e-9))))]
             for k in range(n)]
        depth, i = {}, 0
        while (i < len(pieces)) if pieces is not None else \
                (t < t_end - 1e-12 * max(1.0, abs(t_end))):
            rest = t_end - t
            if pieces is not None:
                lam = pieces[i]
                h = (lam - lam_prev) * span
            else:
                if not retry and rest <= min(STRETCH * h_prop, self.h_max * (1.0 + 1e-9)):
                    h = rest               # the caller's step's end in one substep
                else:
                    h = min(h_prop, rest)
                if rest - h < 1e-9 * span:
                    h = rest
                lam = 1.0 if h == rest else (t + h - t0) / span
            if jaw is not None and self.op.set_pose(jaw.at(lam_prev), jaw.at(lam), lam) \
                    and self.online is not None:
                self.online.set_pose()
            self._before_substep(q)
            stage = StageR(q, v, h, prev, self.op.L_n)
            q_new, its, why = newton(q, v, h, act.at(lam), t0 + lam * span, stage)
            stats.newton_iterations += its
            if q_new is None:
                self._Kb = None
                if pieces is not None:
                    d = depth.get(round(lam_prev, 12), 0)
                    if d >= MAX_SPLITS:
                        stats.reason = f"at t = {t0 + lam * span:.6g} s: {why}"
                        return False, q, v
                    stats.cutbacks += 1
                    pieces[i:i + 1] = [lam_prev + (lam - lam_prev) * (k + 1) / 4
                                       for k in range(4)]
                    depth[round(lam_prev, 12)] = d + 1
                    continue
                if h > h_prop * (1.0 + 1e-9):          # a stretched substep: at the proposal
                    stats.rejected += 1
                    retry = True
                    continue
                run += 1
                if run > MAX_SPLITS:
                    stats.reason = f"at t = {t0 + lam * span:.6g} s: {why}"
                    return False, q, v
                stats.cutbacks += 1
                h_prop, retry = h / 4, True
                continue
            err = 0.0
            if adaptive:
                est = (self.op.V @ (stage.factor * (q_new - stage.p))).reshape(-1, 3)
                err = float(np.sqrt((est * est).sum(axis=1)).max(initial=0.0)) / self.tol
                if err > 1.0:
                    stats.rejected += 1
                    retry = True
                    h_prop = h * growth(err, err_prev, self.order, pi=False)
                    continue
            run, retry = 0, False
            v_new = stage.velocity(q_new, q, prev)
            self.last = (q, v, h, stage)
            self._kb_age += 1
            self._a_prev = (v_new - v) / h
            if self.integrator == "bdf2":
                prev = (q, v, h, self.op.L_n)
            q, v, t, lam_prev, i = q_new, v_new, t + h, lam, i + 1
            stats.substeps += 1
            stats.h_min, stats.h_max = min(stats.h_min, h), max(stats.h_max, h)
            if adaptive:
                grow = growth(err, err_prev, self.order, pi=self.order == 2)
                err_prev = max(err, 1e-4)
                landed = h < h_prop and grow >= 1.0
                h_prop = min(max(h * grow, h_prop) if landed else h * grow, self.h_max)
        self.history, self.err_prev = prev, err_prev
        if adaptive:
            self.h = h_prop
        return True, q, v

    # -- modified Newton ------------------------------------------------------------------
    def _factor(self):
        J = self._A + self._Kb + self._Ks
        if self._Kn is not None:
            J = J + self._bd * self._Kn
        if not np.all(np.isfinite(J)):
            return False
        lu, piv = sla.lu_factor(J, check_finite=False)
        d = np.abs(np.diag(lu))
        if not d.min() > 1e-13 * d.max():      # exactly or numerically singular
            return False
        self._lu = (lu, piv.astype(np.int64))
        self.stats["factorizations"] += 1
        return True

    def _fresh_switching(self, q, parts=None):
        """Rebuild the tangents of the switching parts (all, or the list parts) at q."""
        on = self.online
        if parts is None:
            parts = range(on.parts)
        for i in parts:
            self._Kparts[i] = on.switching_tangent(q, i)
            self.stats["switch_tangents"] += 1
        self._Ks = sum(self._Kparts)
        self._sets = on.active_sets()
        self._lu = None

    def _fresh_bricks(self, q, q_n):
        """Rebuild the damping's tangent (Kn on the shape at q_n) and, when older than
        kb_every substeps, the bricks'; False if a brick inverts."""
        if self._Kb is None or self._kb_age >= self.kb_every:
            if not self.online.brick_tangent(q):
                return False
            self._Kb = self.online.stiffened_tangent()
            self._a_kb = self.online.a
            self._kb_age = 0
            self.stats["brick_tangents"] += 1
        elif self.online.a is not self._a_kb:     # same shape, the current activations
            self._Kb, self._a_kb = self.online.stiffened_tangent(), self.online.a
        if self._current:
            self._Kn = self.online.damping_tangent()       # on the shape at q_n
            self.stats["damping_builds"] += 1
        self._lu = None
        return True

    def _newton(self, q_n, v_n, h, a, t, stage):
        on, M = self.online, self.M_r
        c = stage.c
        on.set_activation(a)
        bdf2 = stage.coef[2] != 0.0
        if self._current:
            # the damping force c beta K_n (u - u_d) (exact, matrix-free), K_n on the
            # predicted shape (BDF2) or the start's; c alpha M (q - q_d) below
            if bdf2:
                bd = on.prepare_damping(stage.p, self.beta * c, start=False,
                                        ref=(stage.q_d, stage.L_d))
            else:
                bd = on.prepare_damping(q_n, self.beta * c)
            if not bd > 0.0:
                return None, 0, "inverted brick"
            C = self.alpha * self.M_damp
        else:
            C = self.C_r
        if self._A_key != c:
            self._A = (c * c) * M + c * C
            self._A_key, self._bd, self._lu = c, self.beta * c, None
        A = self._A
        b = (c * c) * (M @ stage.q_m) + c * (C @ stage.q_d)
        if not self._current and self.beta and self.op.moving:
            # damping "rest": the jaw's motion damped by K_n on the shape at q_n all the same
            b = b - (self.beta / h) * self.op.lifting_damping(q_n)
        if bdf2:
            q = stage.p.copy()
        else:
            q = q_n + h * v_n
            if self._a_prev is not None:      # predictor: the last substep's acceleration
                q = q + (h * h) * self._a_prev
        r_prev, dq, dn_prev = np.inf, None, None
        dq_work = np.empty_like(q)
        # refresh: 0 none, 1 the switching parts, 2 also the bricks and the damping
        refresh = 2 if self._Kb is None else 0
        escalated = 0                         # the level of the last refresh this substep
        for it in range(1, self.max_iter + 1):
            f, jmin = on.forces(q)
            if not jmin > 0.0:
                return None, it, "inverted brick"
            R = A @ q - b + f
            rn = math.sqrt(float(R @ R))
            if not math.isfinite(rn):
                return None, it, "NaN"
            if dq is not None and rn > self.grow * r_prev:
                # the residual grew tenfold (a contact switching on or off): go back half
                # the step, evaluate there, with fresher tangents
                dq *= 0.5
                q = q - dq
                refresh = min(escalated + 1, 2)
                self.stats["backtracks"] += 1
                continue
            if refresh == 2:
                if not self._fresh_bricks(q, q_n):
                    return None, it, "inverted brick"
            if refresh:
                self._fresh_switching(q)
                escalated, refresh = max(escalated, refresh), 0
            else:
                # a cable going slack or a contact opening or closing: that part's tangent
                sets = on.active_sets()
                changed = [i for i, (x, y) in enumerate(zip(sets, self._sets)) if x != y]
                if changed:
                    self._fresh_switching(q, changed)
            if self._lu is None and not self._factor():
                return None, it, "singular reduced tangent"
            lu_solve_small(*self._lu, R, dq_work)
            dq = dq_work.copy()
            q = q + dq
            dn = math.sqrt(float(dq @ dq))
            if not math.isfinite(dn):
                return None, it, "NaN"
            # linear convergence at the rate theta: the error left after this correction
            # is about theta / (1 - theta) |dq| (theta of this substep, or the last one's)
            theta = dn / dn_prev if dn_prev else self._theta
            if dn <= self.utol and theta < 1.0 and theta * dn <= (1.0 - theta) * self.utol:
                if dn_prev:
                    self._theta = min(max(theta, 0.05), 0.9)
                return q, it, ""
            if (dn_prev is not None and dn > self.rate * dn_prev) or it >= self.max_frozen:
                refresh = min(escalated + 1, 2)   # slow: fresher tangents next iteration
                self.stats["slow"] += 1
            r_prev, dn_prev = rn, dn
        return None, self.max_iter, f"no convergence in {self.max_iter} iterations"
