r"""Implicit time stepping: backward Euler with error-controlled adaptive substeps.

Why backward Euler: the face is strongly overdamped (with alpha = 40 1/s and beta = 0.03 s
every mode has a damping ratio >= 1.1) and stiff (K/mu = 500), so the integrator must be
L-stable: high modes are damped out, never amplified, whatever the step. Backward Euler is
L-stable and first order; it dissipates energy (with alpha = beta = 0 a released block
oscillates with a decaying amplitude: for a mode of frequency w the amplitude shrinks by
1/sqrt(1 + (w h)^2) per step and the frequency is low by about (w h)^2 / 3).

Equations for the step t_n -> t_n + h, with u = u_{n+1}:
v_{n+1} = (u - u_n)/h, a_{n+1} = (v_{n+1} - v_n)/h and M a + C v + f_int(u) = f_ext,
solved by Newton (solver.newton) with the inertia and damping terms.

Substeps: a caller's step [t0, t1] is split as needed and lands exactly on t1. Loads (the
activations, prescribed displacements, forces) ramp linearly from their values at t0 to
their targets at t1 (``hold="ramp"``, a first-order hold) or jump at t0 (``hold="step"``).
Local error estimate of a substep: err = h/2 ||v_{n+1} - v_n||_inf (mm), the difference
between backward and forward Euler displacements; a substep is accepted when
err <= tol, and the next step is h * clip(0.9 sqrt(tol / err), 0.3, 2), at most max_substep.
A substep whose Newton fails is retried at h/4 (a cutback); after ``max_cutbacks`` in a row
the caller's step fails and the model goes back to its state at t0.
"""

from dataclasses import dataclass, field

import numpy as np

from .errors import ParameterError
from .newton import newton
from .terms.inertia import Damping, Inertia
from .units import TISSUE_DENSITY


@dataclass
class StepStats:
    """What a caller's step took."""

    converged: bool = True
    substeps: int = 0
    newton_iterations: int = 0
    cutbacks: int = 0
    rejected: int = 0
    h_min: float = np.inf
    h_max: float = 0.0
    reason: str = ""
    history: list = field(default_factory=list)     # (t, h, iterations) per accepted substep


class Transient:
    """Time stepping of a solver.Model (or a FaceModel's model).

    density tonne/mm^3; alpha 1/s, beta s; inertia / damping: include the terms;
    tol: local error tolerance (mm); max_substep, min_substep (s); hold 'ramp' | 'step';
    fixed_step: if set, substeps of exactly that size (no error control; tests of order).
    """

    def __init__(self, model, density=TISSUE_DENSITY, alpha=40.0, beta=0.03, inertia=True,
                 damping=True, tol=1e-3, max_substep=5e-3, min_substep=1e-7, hold="ramp",
                 max_cutbacks=8, fixed_step=None):
        for name, v in (("density", density), ("alpha", alpha), ("beta", beta)):
            if not (np.isfinite(v) and v >= 0):
                raise ParameterError(f"{name} = {v!r} must be a finite number >= 0")
        if not (tol > 0 and max_substep > 0 and 0 < min_substep <= max_substep):
            raise ParameterError("need tol > 0 and 0 < min_substep <= max_substep")
        if hold not in ("ramp", "step"):
            raise ParameterError(f"hold = {hold!r} must be 'ramp' or 'step'")
        self.model = model
        self.tol, self.max_substep, self.min_substep = tol, max_substep, min_substep
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
        self.dissipated = 0.0          # mJ: sum over substeps of h v^T C v (never negative)

    def energy(self):
        """(kinetic, stored) energy in mJ at the current state (stored: all potentials
        of the model's terms other than inertia and damping)."""
        kin = self.inertia.kinetic_energy(self.v) if self.inertia else 0.0
        sysm = self.model.system()
        others = [t for t in sysm.terms if t not in self.step_terms]
        from .assembly import Assembly
        asm = Assembly(sysm.pattern, False)
        st = sysm.state(self.model.u.ravel())
        for term, ids in zip(sysm.terms, sysm._ids):
            if term in others:
                term.assemble(st, asm, ids)
        return kin, asm.energy

    def _substep(self, sysm, u_n, v_n, h, targets, opts):
        for term in self.step_terms:
            term.prepare(h, u_n.reshape(-1, 3), v_n.reshape(-1, 3))
        u, _, rep = newton(sysm, u_n + h * v_n, targets, self.model.linear_solver, opts)
        if u is None:
            u, _, rep2 = newton(sysm, u_n, targets, self.model.linear_solver, opts)
            rep2.iterations += rep.iterations
            rep = rep2
        return u, rep

    def advance(self, t_end):
        """Integrate from self.t to t_end (> self.t); returns StepStats. On failure the
        model, velocity and time stay at their values at the start of the call."""
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
        stats = StepStats()
        t, run = t0, 0
        h = self.fixed_step or min(self.h, self.max_substep)
        while t < t_end - 1e-12 * max(1.0, abs(t_end)):
            h = min(h, t_end - t)
            t_new = t + h
            if t_end - t_new < 1e-9 * span:
                t_new, h = t_end, t_end - t
            lam = 1.0 if self.hold == "step" else (t_new - t0) / span
            sysm.lam, sysm.t = lam, t_new
            targets = p_start + lam * (p_target - p_start)
            u_new, rep = self._substep(sysm, u, v, h, targets, opts)
            stats.newton_iterations += rep.iterations
            if u_new is None:
                stats.cutbacks += 1
                run += 1
                if run > self.max_cutbacks or h / 4 < self.min_substep:
                    stats.converged = False
                    stats.reason = f"at t = {t_new:.6g} s: {rep.reason}"
                    model.u = u0.reshape(-1, 3)
                    self.v = v0.reshape(-1, 3)
                    self.dissipated = d0
                    sysm.lam = 0.0
                    return stats
                h /= 4
                continue
            run = 0
            v_new = (u_new - u) / h
            err = 0.5 * h * float(np.abs(v_new - v).max())
            if self.fixed_step is None and err > self.tol and h > self.min_substep * 1.0001:
                stats.rejected += 1
                h = max(h * max(0.3, 0.9 * np.sqrt(self.tol / err)), self.min_substep)
                continue
            if self.damping is not None:
                self.dissipated += h * float(v_new.ravel() @ self.damping.force(v_new))
            u, v, t = u_new, v_new, t_new
            sysm.commit(u)
            stats.substeps += 1
            stats.h_min, stats.h_max = min(stats.h_min, h), max(stats.h_max, h)
            stats.history.append((t, h, rep.iterations))
            if self.fixed_step is None:
                grow = 2.0 if err == 0 else min(2.0, max(0.3, 0.9 * np.sqrt(self.tol / err)))
                h = min(h * grow, self.max_substep)
                self.h = h
        self.t = t_end
        model.u = u.reshape(-1, 3).copy()
        self.v = v.reshape(-1, 3).copy()
        return stats
