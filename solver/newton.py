r"""Newton-Raphson with a residual line search, on the free DOFs of a System.

Convergence (all must hold at an iterate):

    ||r_f||_2      <= rtol * r_ref + atol        force criterion, N
    ||du||_inf     <= utol                       displacement criterion, mm
                                                 (vacuous at the start point: a state
                                                 already in equilibrium takes no step)

where r_f is the residual on the free DOFs and r_ref = max(||f_int||_2 over all DOFs,
||f_ext||_2, 1e-12 N) at the current iterate (the load scale, reactions included).
The update solves K_ff du_f = -(r_f + K_fp du_p), where du_p brings the prescribed DOFs
to their targets, so that a step's predictor is the consistent linearization.

Line search: while prescribed DOFs move (du_p != 0) the linearized residual vanishes
along the whole step, so the step is only shortened (halved) until admissible. Otherwise,
along du, g(s) = du . r(u + s du) (g(0) < 0 for a descent direction). Newton's step
s = 1 is kept when the state is admissible (no det F <= 0) and |g(1)| <= 0.5 |g(0)|, or
when g(1) has the sign of g(0) (still descending) and ||r|| did not grow (else s is
halved until it did not: a contact kink ahead). Else g changed sign: its root is bracketed
in (0, 1) and found by false position with the Illinois modification (the end that stays
put twice has its g halved), which converges where plain secant steps cycle, as they did
on the penalty kinks of lip/lip contact; the first s with |g(s)| <= 0.5 |g(0)| is
taken, else the best one after max_ls + 4 evaluations.
An iterate whose residual is NaN or that keeps growing (``diverge_factor`` above the
larger of the first two residuals) or that stalls (not halved over ``stall_window``
iterations, checked from iteration stall_window + 4 on) fails the step, and the caller
cuts back.
"""

from dataclasses import dataclass, field

import numpy as np

from .terms.base import InvertedElement


@dataclass
class NewtonOptions:
    rtol: float = 1e-6
    atol: float = 1e-10
    utol: float = 1e-5
    max_iter: int = 25
    max_ls: int = 6
    diverge_factor: float = 1e6
    stall_window: int = 4


@dataclass
class NewtonReport:
    converged: bool
    iterations: int
    residuals: list = field(default_factory=list)   # ||r_f|| at each iterate
    reason: str = ""


class NewtonFailure(Exception):
    pass


def _direction(system, r, data, dup, free, prescribed, lin):
    rhs = -r[free]
    if len(prescribed) and np.any(dup):
        full = np.zeros(system.ndof)
        full[prescribed] = dup
        rhs -= (system.pattern.matrix(data) @ full)[free]
    lin.factorize(system.reduction.matrix(data))
    duf = lin.solve(rhs)
    du = np.zeros(system.ndof)
    du[free] = duf
    du[prescribed] = dup
    return du


def _trial(system, u, du, s):
    """Residual at u + s du, or None where the state is not admissible."""
    try:
        return system.residual(u + s * du)
    except InvertedElement:
        return None


def _admissible_fraction(system, u, du, opts):
    """Largest s in 1, 1/2, 1/4, ... at which the state is admissible, or None."""
    s = 1.0
    for _ in range(opts.max_ls):
        r = _trial(system, u, du, s)
        if r is not None and np.all(np.isfinite(r)):
            return s
        s *= 0.5
    return None


def _g(du, r):
    return None if r is None or not np.all(np.isfinite(r)) else float(du @ r)


def _line_search(system, u, du, r0, opts):
    """Step length s along du: 1 when acceptable, else a root of g(s) = du . r(u + s du)
    bracketed in (0, 1) by false position (Illinois), else the best s tried."""
    g0 = float(du @ r0)
    n0 = float(np.linalg.norm(r0))
    r1 = _trial(system, u, du, 1.0)
    g1 = _g(du, r1)
    if g1 is not None and abs(g1) <= 0.5 * abs(g0):
        return 1.0
    if g1 is not None and g1 * g0 > 0:  # still descending at s = 1
        s, r = 1.0, r1
        for _ in range(opts.max_ls):    # backtrack while the residual grew (a kink)
            if float(np.linalg.norm(r)) <= n0:
                return s
            r = _trial(system, u, du, 0.5 * s)
            if _g(du, r) is None:       # keep the last admissible s
                break
            s *= 0.5
        return s
    lo, glo = 0.0, g0
    hi, ghi = 1.0, g1
    while ghi is None:                  # inadmissible at s = 1: halve into the admissible
        hi *= 0.5
        if hi < 0.5 ** opts.max_ls:
            return None
        ghi = _g(du, _trial(system, u, du, hi))
        if ghi is not None and (abs(ghi) <= 0.5 * abs(g0) or ghi * g0 > 0):
            return hi
    best = (hi, abs(ghi))
    side = 0
    for _ in range(opts.max_ls + 4):
        s = hi - ghi * (hi - lo) / (ghi - glo)
        if not lo < s < hi:
            s = 0.5 * (lo + hi)
        g = _g(du, _trial(system, u, du, s))
        if g is None:                   # inadmissible inside the bracket: shrink from above
            hi = s
            continue
        if abs(g) < best[1]:
            best = (s, abs(g))
        if abs(g) <= 0.5 * abs(g0):
            return s
        if g * g0 > 0:                  # root lies above s
            lo, glo = s, g
            if side == -1:
                ghi *= 0.5              # Illinois: halve the stale end
            side = -1
        else:
            hi, ghi = s, g
            if side == 1:
                glo *= 0.5
            side = 1
    return best[0]


def newton(system, u0, targets, lin, opts):
    """Solve system.residual(u) = 0 on the free DOFs with u[prescribed] = targets.

    system   has ndof, free, prescribed, pattern, reduction, assemble(u) -> (r, data),
             residual(u) -> r, external_scale() -> N
    u0       (ndof,) start; targets (len(prescribed),)
    Returns (u, r, NewtonReport); u is None when the iteration failed, r the residual
    (ndof,) at u (reactions on the prescribed DOFs).
    """
    u = u0.copy()
    free, prescribed = system.free, system.prescribed
    report = NewtonReport(False, 0)
    for it in range(opts.max_iter + 1):
        try:
            r, data = system.assemble(u)
        except InvertedElement as exc:
            report.reason = str(exc)
            return None, None, report
        rf = r[free]
        rn = float(np.linalg.norm(rf))
        report.residuals.append(rn)
        if not np.isfinite(rn):
            report.reason = "residual is not finite"
            return None, None, report
        dup = targets - u[prescribed]
        ref = max(float(np.linalg.norm(r[prescribed])), system.external_scale(), 1e-12)
        if rn <= opts.rtol * ref + opts.atol and not np.any(dup) \
                and (it == 0 or step_size <= opts.utol):     # at it = 0: nothing to move
            report.converged = True
            return u, r, report
        if it == opts.max_iter:
            report.reason = f"no convergence in {opts.max_iter} iterations (||r|| = {rn:.3g} N)"
            return None, None, report
        if it > 2 and rn > opts.diverge_factor * max(report.residuals[:2]):
            report.reason = f"diverging (||r|| = {rn:.3g} N)"
            return None, None, report
        if it >= opts.stall_window + 4 and rn > 0.5 * report.residuals[it - opts.stall_window]:
            report.reason = (f"stalled (||r|| = {rn:.3g} N, not halved in "
                             f"{opts.stall_window} iterations)")
            return None, None, report
        try:
            du = _direction(system, r, data, dup, free, prescribed, lin)
        except RuntimeError as exc:           # singular factorization
            report.reason = f"linear solver failed: {exc}"
            return None, None, report
        if not np.all(np.isfinite(du)):
            report.reason = "linear solve gave a non-finite update (singular tangent?)"
            return None, None, report
        if np.any(dup):
            s = _admissible_fraction(system, u, du, opts)
        else:
            s = _line_search(system, u, du, r, opts)
        if s is None:
            report.reason = "line search found no admissible state (elements invert)"
            return None, None, report
        u = u + s * du
        step_size = float(np.abs(s * du).max()) if len(du) else 0.0
        report.iterations = it + 1
    return None, None, report
