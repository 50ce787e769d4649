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
when g(1) has the sign of g(0) (still descending) and ||r_f|| did not grow (else s is
halved until it did not: a contact kink ahead). Else g changed sign: its root is bracketed
in (0, 1) and found by false position with the Illinois modification (the end that stays
put twice has its g halved), which converges where plain secant steps cycle, as they do
on the penalty kinks of lip/lip contact; the first s with |g(s)| <= 0.5 |g(0)| is
taken, else the best one after max_ls + 4 evaluations. The norms of these tests are
those of the residual on the free DOFs: the reactions on the prescribed ones are the
load's, and near convergence their rounding would decide the test and cut good steps
short.

Secant model (``secant_search``): where the system has nonsmooth terms (contact), a step
that fails the test at s = 1 is searched for on the model

    r~(s) = (1 - s) r_s(0) + s r_s(1) + r_c(s),

r_c the nonsmooth terms' residual evaluated at u + s du (System.nonsmooth_residual), r_s
= r - r_c the rest, interpolated between the two ends already evaluated: exact at both
ends, in between off by the tissue's curvature along one Newton step, where the contact's
kinks and jumps are what the search must find. The model's step (tests as above, to
|g| <= |g0| / 4 within 30 of its evaluations) is then evaluated whole and kept if it
meets the test the model met, or if the model's search ended at its best step (a jump
in the contact force, where g has no root: the exact search ends there too, after many
more residuals) and the state is admissible; else the exact search runs. That evaluation
is the next iterate's residual. A contact evaluation costs a small part of a residual
(the contact's nodes only), so the model's search saves most of the residuals of an
exact one (docs/dev-notes/fast_path.md).

An iterate whose residual is NaN or that keeps growing (``diverge_factor`` above the
larger of the first two residuals) or that stalls (not halved over ``stall_window``
iterations, checked from iteration stall_window + 4 on) fails the step, and the caller
cuts back. So do ``stuck_after`` line searches in a row that cut the step to s <=
``stuck_fraction``: the iterate sits at a jump of the residual, where g changes sign with
no root and the search ends at the jump. Such a jump: a lip slave whose nearest
triangle switches between two equidistant faded (free) regions, each with its own face
normal (a jump in the force at a rounding-level move); without this test each such
iterate runs on until the stall test fails it.

Factorization reuse (``reuse``; the default None: in calls with a key, i.e. the substeps
of solver.core.transient, not in static solves, which keep full Newton): modified Newton.
The update solves K(u_j) du_f = -r_f(u_k) with the factorization of the tangent at an
earlier iterate u_j (j <= k, possibly of an earlier call on the same system: an earlier
substep), which converges linearly, at a rate ||I - K(u_j)^-1 K(u_k)||, for as long as
u_k stays close to u_j. The tangent is assembled and refactorized at u_k when

    * there is no factorization for this system and key (the caller's parameters of
      the tangent, e.g. the time step: first call, new constraints, another step
      size, or the caller invalidated it), or
    * convergence slowed: ||r_f(u_k)|| > refactor_ratio * ||r_f(u_{k-1})|| while the
      force criterion does not hold yet (once it does, only the step must shrink below
      utol, and the residual may sit at rounding), or the rate of the last iteration,
      kept up, would not meet the force criterion within max_iter - 2 iterations, or
    * prescribed DOFs move (du_p != 0; the right-hand side needs K_fp), or
    * the reused direction is not one of descent (du . r >= 0 while the force criterion
      does not hold; a positive definite K(u_j) gives du . r = -r K(u_j)^-1 r < 0).

The convergence criteria and the failure tests are those above. A reused
factorization's direction is taken at its full step or not at all: when the full step
fails the line search's test for s = 1 (or, once the force criterion holds, when ||r||
grew), the step is dropped (counted in NewtonReport.stale_steps) and the tangent is
factorized at u_k for a Newton step with the line search. A stale direction that
overshoots is a poor one to search along: the search cuts such a step to a small
fraction over many residual evaluations, and the next iterate refactorizes anyway (a
stale tangent lacks the stiffness of a contact that has closed since it was made). On a
reused factorization an iterate
costs a residual and a solve (no tangent), and the residual at the accepted step, when it
was the last one evaluated, is the next iterate's. Once a step has been dropped in a
call (``krylov_after_stale``, on by default), the later iterates of the call skip the
plain reused direction (the Krylov one below, else a new factorization). A failed solve
invalidates the factorization. ``reuse = False`` is full Newton: the tangent assembled and
factorized at every iterate.

Partial refresh (``partial_refresh``; the default None: as reuse): where the system has
nonsmooth terms (contact), a refactorization for a key that already has one (convergence
slowed, a stale step dropped, no descent) assembles only the nonsmooth terms' tangent at
u_k (System.nonsmooth_tangent) and adds the rest of the key's last full assembly at u_j
(kept on the linear solver as that assembly minus its nonsmooth part): the factorized
matrix is K_smooth(u_j) + K_contact(u_k). Within a
substep the tissue's tangent changes little (without contact a substep converges fast on
its first factorization) while the contact's is what slows the iteration
(docs/dev-notes/fast_path.md). Only within ``partial_reach`` (mm,
the largest nodal displacement) of the full assembly's state: farther (a large jump, the
bar of tests/test_fast_path.py) the tissue's tangent may be what went stale, and
everything is assembled; a new key (the next substep) assembles everything too.

Contact status (``contact_update``; the default None: in calls with a key, i.e. the
substeps of solver.core.transient, as reuse): every direction, on a new or a reused
factorization, is corrected for the contact status that the step predicts, by low-rank
updates of the factorization (solver.core.contact_update): a slave that the step would carry
into a master meets its contact stiffness in this direction already instead of at the
next iterate, after a line search cut short at its kink. The residual, the line search and
the convergence criteria are unchanged.

Krylov directions (``krylov``; the default None: as contact_update): where a reused
factorization's plain direction would not do (convergence slowed, its full step failed,
or no descent), before refactorizing, the direction solves the tangent with the contact
terms' part at u_k (and the status that the step predicts) by GMRES preconditioned with
the factorization, its earlier solves recycled (solver.core.krylov); it is searched along like
a new factorization's direction, and where GMRES does not reach its tolerance within its
budget of solves the tangent is refactorized. It trades factorizations for solves, so
it saves most where a factorization costs many solves (SuperLU) and least with
single-precision PARDISO, whose factorization costs only a few (docs/benchmarks.md,
docs/dev-notes/fast_path.md).
"""

from dataclasses import dataclass, field, replace

import numpy as np

from solver.core.contact_update import ContactUpdate
from solver.core.krylov import KrylovDirection
from solver.core.linsolve import single_threaded_blas
from solver.core.terms.base import InvertedElement


@dataclass
class NewtonOptions:
    rtol: float = 1e-6
    atol: float = 1e-10
    utol: float = 1e-5
    max_iter: int = 25
    max_ls: int = 6
    diverge_factor: float = 1e6
    stall_window: int = 4
    # Fail (the caller cuts back) after stuck_after line searches in a row that cut the
    # step to s <= stuck_fraction while the force criterion does not hold: the iterate sits
    # at a jump of the residual that no direction passes (module docstring).
    stuck_fraction: float = 1e-6
    stuck_after: int = 2
    reuse: bool | None = None       # reuse factorizations; None: where the caller gives a key
    # Refactorize when ||r_f|| fell by less than this factor. A reused iteration costs a
    # residual and a solve, a new factorization about six to seven of them (an assembly
    # with the tangent, the factorization, the line search's residuals), so a rate of 0.7
    # pays: 0.7^7 = 0.08. Where lip contact changes status between iterates a new tangent
    # does not converge fast either. On benchmarks/fast_path.py 0.7 needs fewer
    # factorizations than 0.5 or 0.1 for the same outputs, and 0.8 gains nothing
    # (docs/dev-notes/fast_path.md).
    # Below the stall test's 0.5 ** (1 / stall_window) = 0.84.
    refactor_ratio: float = 0.7
    # Correct each direction for the contact status the step predicts, by low-rank updates
    # of the factorization (solver.core.contact_update); None: where the caller gives a key (the
    # substeps of solver.core.transient), as reuse. Static solves keep the plain direction: on
    # the reference face's static OOP and OOP + BUC in one load step (as in
    # tests/test_muscle_actions.py, teeth contact) Newton takes more iterations with the
    # correction than without, on the half and on the full face.
    contact_update: bool | None = None
    # Refactorize within a call (the factorization of this key slowed or its step failed)
    # with the smooth terms' tangent of the key's last full assembly, if made within
    # partial_reach, and only the nonsmooth terms' (contact) assembled anew; None: where
    # reuse. Module docstring.
    partial_refresh: bool | None = None
    partial_reach: float = 0.05     # mm: partial refreshes within this of the full assembly
    # Where a reused factorization's direction would not do, solve with the contact terms'
    # tangent at the iterate by GMRES preconditioned with the factorization (solver.core.krylov)
    # before refactorizing, where the system has contact terms and reuse is on; None: as
    # contact_update. Module docstring.
    krylov: bool | None = None
    # Search a step along a new direction on the secant model of the residual (the smooth
    # terms interpolated, the contact evaluated) before evaluating it whole; module
    # docstring.
    secant_search: bool = True
    # Once a reused factorization's step has been dropped in a call, later iterates of that
    # call skip the plain reused direction and go to the Krylov one (or a refactorization):
    # at a soft lip penalty (0.3 N/mm^3) most reused directions of benchmarks/fast_path.py's
    # case a are dropped, and skipping them after the first saves Newton iterations and
    # residuals (docs/dev-notes/fast_path.md).
    krylov_after_stale: bool = True


@dataclass
class NewtonReport:
    converged: bool
    iterations: int
    residuals: list = field(default_factory=list)   # ||r_f|| at each iterate
    reason: str = ""
    factorizations: int = 0
    stale_steps: int = 0            # reused factorizations' steps dropped for a new one


def _direction(system, r, data, dup, lin):
    """du with du_f = -K_ff^-1 (r_f + K_fp du_p) on the current factorization of lin
    (data: the tangent's CSR data, needed only where du_p != 0)."""
    free, prescribed = system.free, system.prescribed
    rhs = -r[free]
    if len(prescribed) and np.any(dup):
        full = np.zeros(system.ndof)
        full[prescribed] = dup
        rhs -= (system.pattern.matrix(data) @ full)[free]
    duf = lin.solve(rhs)
    if not np.any(dup):         # K^-1 (-r_f), GMRES's start on this factorization (krylov)
        lin.plain = (r, lin.factorizations, duf)
    du = np.zeros(system.ndof)
    du[free] = duf
    du[prescribed] = dup
    return du


class _Line:
    """Residuals r(u + s du) along a direction; None where the state is not admissible.
    Remembers the last point evaluated: the terms hold that state's outputs (contact
    forces and gaps), so its residual can stand for the next iterate's only if it is
    the accepted one."""

    def __init__(self, system, u, du):
        self.system, self.u, self.du = system, u, du
        self.last = (None, None)

    def __call__(self, s):
        try:
            r = self.system.residual(self.u + s * self.du)
        except InvertedElement:
            r = None
        self.last = (s, r)
        return r

    def residual_at(self, s):
        """r(u + s du) if s was the last point evaluated (and admissible), else None."""
        return self.last[1] if self.last[0] == s else None


def _admissible_fraction(line, opts):
    """Largest s in 1, 1/2, 1/4, ... at which the state is admissible, or None."""
    s = 1.0
    for _ in range(opts.max_ls):
        r = line(s)
        if r is not None and np.all(np.isfinite(r)):
            return s
        s *= 0.5
    return None


def _g(du, r):
    return None if r is None or not np.all(np.isfinite(r)) else float(du @ r)


class _Secant:
    """The residual along a line with the smooth terms' part interpolated between its
    ends, r~(s) = (1 - s) r_s(0) + s r_s(1) + r_c(s), and only the nonsmooth terms' part
    r_c (contact) evaluated at s (System.nonsmooth_residual): exact at s = 0 and 1; in
    between off by the smooth part's curvature along the step (module docstring)."""

    def __init__(self, line, r0, r1):
        self.system, self.u, self.du = line.system, line.u, line.du
        self.a = r0 - self.system.nonsmooth_residual(self.u)
        self.b = r1 - self.system.nonsmooth_residual(self.u + self.du) - self.a

    def __call__(self, s):
        return self.a + s * self.b + self.system.nonsmooth_residual(self.u + s * self.du)


def _line_search(line, r0, opts):
    """Step length s along du: 1 when acceptable, else a root of g(s) = du . r(u + s du)
    bracketed in (0, 1) by false position (Illinois), else the best s tried; searched on
    the secant model first where the system has nonsmooth terms (opts.secant_search)."""
    du = line.du
    g0 = float(du @ r0)
    n0 = _fnorm(line, r0)
    r1 = line(1.0)
    g1 = _g(du, r1)
    if _full_step_stands(g0, g1, n0, _fnorm(line, r1)):
        return 1.0
    if opts.secant_search and g1 is not None \
            and any(t.nonsmooth for t in line.system.terms):
        s, test = _search(_Secant(line, r0, r1), g0, n0, r1, opts, SECANT_SLOPE, SECANT_EVALS)
        if s is not None and _passes(test, line, line(s), g0, n0):
            return s                    # its residual is the next iterate's (_Line.last)
    return _search(line, g0, n0, r1, opts)[0]


SECANT_SLOPE = 0.25     # the secant model's search aims at |g| <= this * |g0| ...
SECANT_EVALS = 30       # ... within this many of its evaluations


def _fnorm(line, r):
    """||r_f||, the norm of r on the free DOFs (None where r is)."""
    return None if r is None else float(np.linalg.norm(r[line.system.free]))


def _passes(test, line, r, g0, n0):
    """Whether r = r(u + s du) is admissible and meets the test by which the search took
    s ("norm": ||r_f|| <= n0; "slope": |g(s)| <= |g0| / 2; "best": none)."""
    g = _g(line.du, r)
    if g is None:
        return False
    if test == "norm":
        return _fnorm(line, r) <= n0
    return test == "best" or abs(g) <= 0.5 * abs(g0)


def _search(line, g0, n0, r1, opts, slope=0.5, evals=None):
    """_line_search past s = 1 (r1 = r(1), failed) on line (the residual or its secant
    model): (s, the test it met: "norm", "slope" or "best", none met), s None where no
    admissible state was found."""
    du = line.du
    g1 = _g(du, r1)
    if g1 is not None and g1 * g0 > 0:  # still descending at s = 1, the residual grew
        s, r = 1.0, r1
        for _ in range(opts.max_ls):    # backtrack while the residual grew (a kink)
            if _fnorm(line, r) <= n0:
                return s, "norm"
            r = line(0.5 * s)
            if _g(du, r) is None:       # keep the last admissible s
                break
            s *= 0.5
        return s, "best"
    lo, glo = 0.0, g0
    hi, ghi = 1.0, g1
    while ghi is None:                  # inadmissible at s = 1: halve into the admissible
        hi *= 0.5
        if hi < 0.5 ** opts.max_ls:
            return None, "best"
        ghi = _g(du, line(hi))
        if ghi is not None and (abs(ghi) <= 0.5 * abs(g0) or ghi * g0 > 0):
            return hi, "best"
    best = (hi, abs(ghi))
    side = 0
    for _ in range(evals or opts.max_ls + 4):
        s = hi - ghi * (hi - lo) / (ghi - glo)
        if not lo < s < hi:
            s = 0.5 * (lo + hi)
        g = _g(du, line(s))
        if g is None:                   # inadmissible inside the bracket: shrink from above
            hi = s
            continue
        if abs(g) < best[1]:
            best = (s, abs(g))
        if abs(g) <= slope * abs(g0):
            return s, "slope"
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
    return best[0], "best"


def newton(system, u0, targets, lin, opts, key=None):
    """Solve system.residual(u) = 0 on the free DOFs with u[prescribed] = targets.

    system   has ndof, free, prescribed, pattern, reduction, assemble(u) -> (r, data),
             residual(u) -> r, external_scale() -> N
    u0       (ndof,) start; targets (len(prescribed),)
    lin      a solver.core.linsolve solver (its factorization may be reused: opts.reuse)
    key      what the tangent depends on besides u (the transient's step h): a
             factorization is reused only by a call with the same system and key
    Returns (u, r, NewtonReport); u is None when the iteration failed, r the residual
    (ndof,) at u (reactions on the prescribed DOFs). BLAS runs on one thread meanwhile.
    """
    with single_threaded_blas():
        if opts.reuse is None:
            opts = replace(opts, reuse=key is not None)
        if opts.contact_update is None:
            opts = replace(opts, contact_update=key is not None)
        if opts.partial_refresh is None:
            opts = replace(opts, partial_refresh=opts.reuse)
        if opts.krylov is None:
            opts = replace(opts, krylov=opts.contact_update)
        u, r, report = _newton(system, u0, targets, lin, opts, (system.reduction, key))
    if u is None:
        lin.invalidate()
    return u, r, report


def _evaluate(system, u, need_k):
    """(r, data or None) at u, or (None, reason) where the state is not admissible."""
    try:
        if need_k:
            return system.assemble(u)
        return system.residual(u), None
    except InvertedElement as exc:
        return None, str(exc)


def _factorize(system, lin, data, tag, report, u, contact, full=True, opts=None, kc=None,
               krylov=None):
    """Factorize the tangent data (made at u) for tag; full: assembled whole at u, whose
    part without the nonsmooth terms is then kept on lin for partial refreshes
    (opts.partial_refresh), with u; kc: the nonsmooth terms' part at u where known
    (recorded for krylov's directions)."""
    lin.refactor(system.reduction.matrix(data), tag)
    report.factorizations += 1
    keep = full and opts is not None and opts.partial_refresh \
        and any(t.nonsmooth for t in system.terms)
    if kc is None and (keep or krylov):
        kc = system.nonsmooth_tangent(u)
    if keep:
        lin.smooth_tangent = (tag, data - kc, u.copy())
    if krylov:
        krylov.mark(lin, kc)
    if contact:
        contact.mark(lin, u)


def _partial(system, lin, tag, u, reach):
    """(tangent, its nonsmooth part) at u with the smooth terms' part of the last full
    assembly for tag and the nonsmooth terms' part at u, or None where lin keeps no such
    part or that assembly was made farther than reach (mm, max-norm) from u."""
    kept = getattr(lin, "smooth_tangent", None)
    if kept is None or kept[0][0] is not tag[0] or kept[0][1] != tag[1] \
            or np.abs(u - kept[2]).max(initial=0.0) > reach:
        return None
    kc = system.nonsmooth_tangent(u)
    return kept[1] + kc, kc


def _newton(system, u0, targets, lin, opts, tag):
    u = u0.copy()
    prescribed = system.prescribed
    report = NewtonReport(False, 0)
    if len(system.free) == 0:               # every DOF prescribed: nothing to solve
        u[prescribed] = targets
        r, reason = _evaluate(system, u, False)
        if r is None or not np.all(np.isfinite(r)):
            report.reason = reason if r is None else "residual is not finite"
            return None, None, report
        report.converged = True
        report.residuals.append(0.0)
        return u, r, report
    contact = ContactUpdate(system) if opts.contact_update else None
    krylov = KrylovDirection.of(system) if opts.krylov and opts.reuse else None
    krylov = krylov if krylov else None            # no contact terms: plain reuse
    step_size = np.inf                      # of the last update (none yet)
    stuck = 0                               # line searches in a row cut to ~0
    r, data = _evaluate(system, u, not _reusable(lin, opts, tag))
    for it in range(opts.max_iter + 1):
        if r is None:
            report.reason = data
            return None, None, report
        rf = r[system.free]
        rn = float(np.linalg.norm(rf))
        report.residuals.append(rn)
        if not np.isfinite(rn):
            report.reason = "residual is not finite"
            return None, None, report
        dup = targets - u[prescribed]
        ref = max(float(np.linalg.norm(r[prescribed])), system.external_scale(), 1e-12)
        balanced = rn <= opts.rtol * ref + opts.atol
        if balanced and not np.any(dup) \
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
        slow = it > 0 and not balanced and _slow(rn, report.residuals[it - 1],
                                                 opts.rtol * ref + opts.atol, it, opts)
        slow = slow or (opts.krylov_after_stale and report.stale_steps > 0)
        try:
            du, data, mode = _update(system, u, r, data, dup, lin, opts, tag, slow,
                                     balanced, report, contact, krylov)
            line = _Line(system, u, du)
            if mode == "reused" and not _full_step_taken(line, r, balanced):
                report.stale_steps += 1         # a Krylov direction or a new tangent
                du, data, mode = _update(system, u, r, data, dup, lin, opts, tag, True,
                                         balanced, report, contact, krylov)
                line = _Line(system, u, du)
        except RuntimeError as exc:           # singular factorization
            report.reason = f"linear solver failed: {exc}"
            return None, None, report
        if not np.all(np.isfinite(du)):
            report.reason = "linear solve gave a non-finite update (singular tangent?)"
            return None, None, report
        if mode == "reused":
            s = 1.0
        elif np.any(dup):
            s = _admissible_fraction(line, opts)
        else:
            s = _line_search(line, r, opts)
        if s is None:
            report.reason = "line search found no admissible state (elements invert)"
            return None, None, report
        u = u + s * du
        step_size = float(np.abs(s * du).max()) if len(du) else 0.0
        report.iterations = it + 1
        stuck = stuck + 1 if s <= opts.stuck_fraction and not balanced else 0
        if stuck >= opts.stuck_after:
            report.reason = (f"stuck: {stuck} line searches in a row cut the step to "
                             f"s <= {opts.stuck_fraction:g} (a jump in the residual"
                             f"{_jump_sites(_Line(system, u, du), line.residual_at(s))})")
            return None, None, report
        r = line.residual_at(s) if opts.reuse else None
        data = None
        if r is None:
            r, data = _evaluate(system, u, not opts.reuse)
    return None, None, report


def _jump_sites(line, r0, count=3, bisections=40):
    """Where the residual jumps along line (from its u, whose residual is r0, or None)
    towards the full step: bisection on g(s) = du . r(u + s du) between s = 0 and 1 to a
    bracket of width 2^-bisections, then ", largest at node i (x N), ..." for the `count`
    nodes whose free DOFs' residual differs most across it ("" where g does not change
    sign, or a state is not admissible). Called when Newton fails stuck, to name the
    nodes of the jump (a contact slave switching faces, say)."""
    free = line.system.free
    r0 = line(0.0) if r0 is None else r0
    r1 = line(1.0)
    g0, g1 = _g(line.du, r0), _g(line.du, r1)
    if g0 is None or g1 is None or g0 * g1 > 0:
        return ""
    lo, hi = (0.0, r0, g0), (1.0, r1, g1)
    for _ in range(bisections):
        mid = 0.5 * (lo[0] + hi[0])
        r = line(mid)
        g = _g(line.du, r)
        if g is None:
            return ""
        if g * lo[2] > 0:
            lo = (mid, r, g)
        else:
            hi = (mid, r, g)
    d = np.zeros(len(r0))
    d[free] = np.abs(hi[1][free] - lo[1][free])
    per_node = np.sqrt((d.reshape(-1, 3) ** 2).sum(axis=1))
    top = [int(i) for i in np.argsort(per_node)[::-1][:count] if per_node[i] > 1e-12]
    if not top:
        return ""
    return ", largest at " + ", ".join(f"node {i} ({per_node[i]:.3g} N)" for i in top)


def _slow(rn, prev, tol, it, opts):
    """Whether the residual rn, after prev at the iteration before, calls for a new
    factorization: it fell by less than refactor_ratio (or not at all), or at that rate
    the force tolerance tol (< rn: not met yet) would not be met within the max_iter - 2
    iterations left."""
    if rn > opts.refactor_ratio * prev or rn >= prev:
        return True
    needed = np.log(tol / rn) / np.log(rn / prev)          # both logarithms negative
    return it + needed > opts.max_iter - 2


def _reusable(lin, opts, tag):
    """Whether lin holds a factorization made for tag = (reduction, key)."""
    return opts.reuse and lin.tag is not None and lin.tag[0] is tag[0] and lin.tag[1] == tag[1]


def _update(system, u, r, data, dup, lin, opts, tag, slow, balanced, report, contact,
            krylov=None):
    """(du, data, mode): Newton's update at u, on a reused factorization where that is
    allowed (module docstring; balanced: the force criterion holds, so that r is at the
    level of rounding and du . r may have any sign), else on a new one of the tangent at u
    (assembled if data is None: the residual is then evaluated again with it); corrected
    for the predicted contact status where contact (a ContactUpdate) is given. With krylov
    (a KrylovDirection), where the reused factorization's plain direction would not do
    (slow, or no descent), its GMRES solution with the contact's tangent at u before a
    new factorization. mode: "reused", "krylov" or "new"."""
    fix = contact and not np.any(dup)
    reusable = _reusable(lin, opts, tag)
    if reusable and not np.any(dup):
        tries = ([] if slow else ["reused"]) + (["krylov"] if krylov else [])
        for mode in tries:
            if mode == "krylov":
                du = krylov.direction(lin, u, r)
            else:
                du = _direction(system, r, None, dup, lin)
                du = contact.correct(lin, u, du) if fix else du
            if du is not None and np.all(np.isfinite(du)) \
                    and (balanced or float(du @ r) < 0.0):
                return du, data, mode
    full, kc = data is not None, None
    if data is None and reusable and opts.partial_refresh and not np.any(dup):
        data, kc = _partial(system, lin, tag, u, opts.partial_reach) or (None, None)
    if data is None:
        r2, data = _evaluate(system, u, True)
        if r2 is None:
            raise RuntimeError(data)
        full = True
    _factorize(system, lin, data, tag, report, u, contact, full, opts, kc, krylov)
    du = _direction(system, r, data, dup, lin)
    return (contact.correct(lin, u, du) if fix else du), data, "new"


def _full_step_stands(g0, g1, n0, n1, balanced=False):
    """The line search's test for s = 1, with g0 = g(0), g1 = g(1) (None: inadmissible),
    n0, n1 = ||r_f|| at 0 and 1: |g1| <= |g0| / 2, or g1 of the sign of g0 with n1 <= n0
    (balanced: n1 <= n0 whatever the signs)."""
    if g1 is None:
        return False
    kept = n1 <= n0
    return abs(g1) <= 0.5 * abs(g0) or (kept and (balanced or g1 * g0 > 0))


def _full_step_taken(line, r0, balanced):
    """Whether the full step along a reused factorization's direction stands
    (_full_step_stands at s = 1 of line)."""
    r1 = line(1.0)
    return _full_step_stands(float(line.du @ r0), _g(line.du, r1), _fnorm(line, r0),
                             _fnorm(line, r1), balanced)
