r"""Newton-Raphson on the free DOFs of a System, with a line search
(solver.core.linesearch) and, in a transient's substeps, modified Newton.

Convergence (all must hold at an iterate):

    ||r_f||_2      <= rtol * r_ref + atol        force criterion, N
    ||du||_inf     <= utol                       displacement criterion, mm

r_f the residual on the free DOFs, r_ref = max(||f_int||_2, ||f_ext||_2, 1e-12 N) at the
iterate (the load scale, reactions included). The update solves K_ff du_f = -(r_f + K_fp
du_p), du_p bringing the prescribed DOFs to their targets (the consistent linearization of
a step's predictor). While prescribed DOFs move the step is only halved until admissible;
otherwise the line search picks it. A NaN residual, one that grows (``diverge_factor``),
stalls (not halved over ``stall_window`` iterations) or sits at a jump (``stuck_after``
searches in a row cut to s <= ``stuck_fraction``) fails the call; the caller cuts back.

Where the caller gives a key (the substeps of solver.core.transient; static solves keep
full Newton), four devices cut the factorizations, each an option of NewtonOptions:

* ``reuse``: modified Newton. A factorization of an earlier iterate's tangent (of this
  call or an earlier one with the same system and key) is kept while the residual falls
  by at least ``refactor_ratio`` per iteration; a reused direction is taken at its full
  step or dropped for a new tangent.
* ``partial_refresh``: a refactorization within a call adds the nonsmooth terms' tangent
  at the iterate to the smooth terms' of the key's last full assembly (within
  ``partial_reach`` mm of it).
* ``contact_update``: each direction is corrected for the contact status that it
  predicts, by low-rank updates of the factorization (solver.core.contact_update).
* ``krylov``: where a reused direction would not do, GMRES on the tangent with the
  contact's part at the iterate, preconditioned by the factorization (solver.core.krylov),
  before refactorizing.

Only the direction changes: the residual and the criteria are the same, so the solution
is that of full Newton to the tolerance. Derivation and reasons: docs/method.md, section
"Newton's fast path"; the figures behind the defaults: docs/dev-notes/fast_path.md.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from solver.core.contact_update import ContactUpdate
from solver.core import linesearch as ls
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
        lin.notes["plain"] = (r, duf)
    du = np.zeros(system.ndof)
    du[free] = duf
    du[prescribed] = dup
    return du


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
    kept = lin.smooth_tangent
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
            line = ls.Line(system, u, du)
            if mode == "reused" and not ls.full_step_taken(line, r, balanced):
                report.stale_steps += 1         # a Krylov direction or a new tangent
                du, data, mode = _update(system, u, r, data, dup, lin, opts, tag, True,
                                         balanced, report, contact, krylov)
                line = ls.Line(system, u, du)
        except RuntimeError as exc:           # singular factorization
            report.reason = f"linear solver failed: {exc}"
            return None, None, report
        if not np.all(np.isfinite(du)):
            report.reason = "linear solve gave a non-finite update (singular tangent?)"
            return None, None, report
        if mode == "reused":
            s = 1.0
        elif np.any(dup):
            s = ls.admissible_fraction(line, opts)
        else:
            s = ls.line_search(line, r, opts)
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
                             f"{ls.jump_sites(ls.Line(system, u, du), line.residual_at(s))})")
            return None, None, report
        r = line.residual_at(s) if opts.reuse else None
        data = None
        if r is None:
            r, data = _evaluate(system, u, not opts.reuse)
    return None, None, report


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


