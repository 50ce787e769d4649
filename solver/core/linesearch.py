r"""Newton's line search: the step length along a direction du from u, on the residual
r(u + s du) of a System (solver.core.newton).

g(s) = du . r(u + s du), g(0) < 0 for a descent direction. The full step s = 1 stands when
the state is admissible (no det F <= 0) and |g(1)| <= |g(0)| / 2, or when g(1) has the sign
of g(0) (still descending) and ||r_f|| did not grow (else s is halved until it did not: a
contact kink ahead). Else g changed sign: its root is bracketed in (0, 1) and found by
false position with the Illinois modification (the end that stays put twice has its g
halved), which converges where plain secant steps cycle, as they do on the penalty kinks
of lip/lip contact; the first s with |g(s)| <= |g(0)| / 2 is taken, else the best one after
max_ls + 4 evaluations. The norms are those of the residual on the free DOFs: the
reactions on the prescribed ones are the load's, and near convergence their rounding would
decide the test.

Secant model (``NewtonOptions.secant_search``): where the system has nonsmooth terms
(contact), a step that fails the test at s = 1 is searched for first on

    r~(s) = (1 - s) r_s(0) + s r_s(1) + r_c(s),

r_c the nonsmooth terms' residual at u + s du (System.nonsmooth_residual), r_s = r - r_c
interpolated between the two ends already evaluated: exact at both ends, in between off by
the tissue's curvature along one step, where the contact's kinks and jumps are what the
search must find. A contact evaluation costs a small part of a residual, so the model's
search (to |g| <= |g0| / 4 within 30 of its evaluations) saves most of an exact search's
residuals. Its step is then evaluated whole and kept if it meets the test the model met,
or if the model's search ended at its best step (a jump in the contact force, where g has
no root) and the state is admissible; else the exact search runs.

``jump_sites`` names the nodes where the residual jumps along a line, for the message of a
Newton iteration that fails stuck at such a jump.
"""

import numpy as np

from solver.core.terms.base import InvertedElement


class Line:
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


def admissible_fraction(line, opts):
    """Largest s in 1, 1/2, 1/4, ... at which the state is admissible, or None."""
    s = 1.0
    for _ in range(opts.max_ls):
        r = line(s)
        if r is not None and np.all(np.isfinite(r)):
            return s
        s *= 0.5
    return None


def g_of(du, r):
    """g(s) = du . r at a point of the line (r = r(u + s du)); None where r is None or not
    finite (an inadmissible state)."""
    return None if r is None or not np.all(np.isfinite(r)) else float(du @ r)


class Secant:
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


def line_search(line, r0, opts):
    """Step length s along du: 1 when acceptable, else a root of g(s) = du . r(u + s du)
    bracketed in (0, 1) by false position (Illinois), else the best s tried; searched on
    the secant model first where the system has nonsmooth terms (opts.secant_search)."""
    du = line.du
    g0 = float(du @ r0)
    n0 = free_norm(line, r0)
    r1 = line(1.0)
    g1 = g_of(du, r1)
    if full_step_stands(g0, g1, n0, free_norm(line, r1)):
        return 1.0
    if opts.secant_search and g1 is not None \
            and any(t.nonsmooth for t in line.system.terms):
        s, test = _search(Secant(line, r0, r1), g0, n0, r1, opts, SECANT_SLOPE, SECANT_EVALS)
        if s is not None and _passes(test, line, line(s), g0, n0):
            return s                    # its residual is the next iterate's (Line.last)
    return _search(line, g0, n0, r1, opts)[0]


SECANT_SLOPE = 0.25     # the secant model's search aims at |g| <= this * |g0| ...
SECANT_EVALS = 30       # ... within this many of its evaluations


def free_norm(line, r):
    """||r_f||, the norm of r on the free DOFs (None where r is)."""
    return None if r is None else float(np.linalg.norm(r[line.system.free]))


def _passes(test, line, r, g0, n0):
    """Whether r = r(u + s du) is admissible and meets the test by which the search took
    s ("norm": ||r_f|| <= n0; "slope": |g(s)| <= |g0| / 2; "best": none)."""
    g = g_of(line.du, r)
    if g is None:
        return False
    if test == "norm":
        return free_norm(line, r) <= n0
    return test == "best" or abs(g) <= 0.5 * abs(g0)


def _search(line, g0, n0, r1, opts, slope=0.5, evals=None):
    """line_search past s = 1 (r1 = r(1), failed) on line (the residual or its secant
    model): (s, the test it met: "norm", "slope" or "best", none met), s None where no
    admissible state was found."""
    du = line.du
    g1 = g_of(du, r1)
    if g1 is not None and g1 * g0 > 0:  # still descending at s = 1, the residual grew
        s, r = 1.0, r1
        for _ in range(opts.max_ls):    # backtrack while the residual grew (a kink)
            if free_norm(line, r) <= n0:
                return s, "norm"
            r = line(0.5 * s)
            if g_of(du, r) is None:     # keep the last admissible s
                break
            s *= 0.5
        return s, "best"
    lo, glo = 0.0, g0
    hi, ghi = 1.0, g1
    while ghi is None:                  # inadmissible at s = 1: halve into the admissible
        hi *= 0.5
        if hi < 0.5 ** opts.max_ls:
            return None, "best"
        ghi = g_of(du, line(hi))
        if ghi is not None and (abs(ghi) <= 0.5 * abs(g0) or ghi * g0 > 0):
            return hi, "best"
    best = (hi, abs(ghi))
    side = 0
    for _ in range(evals or opts.max_ls + 4):
        s = hi - ghi * (hi - lo) / (ghi - glo)
        if not lo < s < hi:
            s = 0.5 * (lo + hi)
        g = g_of(du, line(s))
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


def jump_sites(line, r0, count=3, bisections=40):
    """Where the residual jumps along line (from its u, whose residual is r0, or None)
    towards the full step: bisection on g(s) = du . r(u + s du) between s = 0 and 1 to a
    bracket of width 2^-bisections, then ", largest at node i (x N), ..." for the `count`
    nodes whose free DOFs' residual differs most across it ("" where g does not change
    sign, or a state is not admissible). Called when Newton fails stuck, to name the
    nodes of the jump (a contact slave switching faces, say)."""
    free = line.system.free
    r0 = line(0.0) if r0 is None else r0
    r1 = line(1.0)
    g0, g1 = g_of(line.du, r0), g_of(line.du, r1)
    if g0 is None or g1 is None or g0 * g1 > 0:
        return ""
    lo, hi = (0.0, r0, g0), (1.0, r1, g1)
    for _ in range(bisections):
        mid = 0.5 * (lo[0] + hi[0])
        r = line(mid)
        g = g_of(line.du, r)
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


def full_step_stands(g0, g1, n0, n1, balanced=False):
    """The line search's test for s = 1, with g0 = g(0), g1 = g(1) (None: inadmissible),
    n0, n1 = ||r_f|| at 0 and 1: |g1| <= |g0| / 2, or g1 of the sign of g0 with n1 <= n0
    (balanced: n1 <= n0 whatever the signs)."""
    if g1 is None:
        return False
    kept = n1 <= n0
    return abs(g1) <= 0.5 * abs(g0) or (kept and (balanced or g1 * g0 > 0))


def full_step_taken(line, r0, balanced):
    """Whether the full step along a reused factorization's direction stands
    (full_step_stands at s = 1 of line)."""
    r1 = line(1.0)
    return full_step_stands(float(line.du @ r0), g_of(line.du, r1), free_norm(line, r0),
                             free_norm(line, r1), balanced)
