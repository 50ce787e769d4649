"""Newton's line search (solver.core.newton): its secant model, its tests on the free DOFs."""

from types import SimpleNamespace

import numpy as np
from conftest import assert_same_lips, gesture_both_ways

from solver.core.linesearch import Line, Secant, line_search
from solver.core.newton import NewtonOptions


class _Lined:
    """A residual along u = s du on DOFs 0..3 (3 prescribed): a linear smooth part with a
    reaction on DOF 3, plus a nonsmooth part on DOF 0 (a force with a kink or a jump at
    s = at); counts the whole residual's evaluations."""

    def __init__(self, kind="kink", at=0.3, reaction=(5.0, 0.0)):
        self.free, self.prescribed = np.arange(3), np.array([3])
        self.terms = [SimpleNamespace(nonsmooth=True)]
        self.kind, self.at, self.reaction = kind, at, reaction
        self.residuals = 0
        self.K = np.diag([1.0, 2.0, 3.0])
        self.b = np.array([-1.0, -0.4, 0.6])

    def _smooth(self, u):
        s = u[0]                                  # du = (1, ...): u[0] is s
        return np.append(self.K @ u[:3] + self.b, self.reaction[0] + self.reaction[1] * s)

    def nonsmooth_residual(self, u):
        s, r = u[0], np.zeros(4)
        if self.kind == "kink":
            r[0] = 8.0 * max(s - self.at, 0.0)   # a contact that closes at s = at
        else:
            r[0] = 3.0 * (s > self.at)            # a force that jumps on at s = at
        return r

    def residual(self, u):
        self.residuals += 1
        return self._smooth(u) + self.nonsmooth_residual(u)


def _line(system):
    du = np.array([1.0, 0.2, -0.2, 0.0])
    return Line(system, np.zeros(4), du)


def test_the_secant_model_is_exact_where_the_smooth_part_is_linear():
    """r~(s) = (1 - s) r_s(0) + s r_s(1) + r_c(s) equals the residual at the ends and, for
    a linear smooth part, everywhere between, kinks of the contact included."""
    system = _Lined("kink")
    line = _line(system)
    model = Secant(line, line(0.0), line(1.0))
    for s in (0.0, 0.1, 0.3, 0.45, 0.8, 1.0):
        assert np.allclose(model(s), system.residual(s * line.du), atol=1e-13)


def test_a_kinked_line_is_searched_on_the_model_with_two_residuals():
    """Past a contact's kink the full step overshoots; the root of g = du . r is found
    on the secant model, and only the full step and the step taken are evaluated whole.
    Without the model the search evaluates the residual at every trial step."""
    found = {}
    for on in (True, False):
        system = _Lined("kink")
        line = _line(system)
        r0 = line(0.0)
        system.residuals = 0
        s = line_search(line, r0, NewtonOptions(secant_search=on))
        g = float(line.du @ system.residual(s * line.du))
        assert abs(g) <= 0.5 * abs(float(line.du @ r0))
        found[on] = (s, system.residuals - 1)
    assert found[True][1] == 2
    assert found[False][1] > 2


def test_a_jump_ends_the_search_at_the_best_step_without_more_residuals():
    """A force that jumps on (g changes sign with no root) exhausts the search's budget;
    on the model that costs no whole residual but the full step's and the step taken's
    (the next iterate's), and the step taken is the best one tried, just below the jump.
    The exact search evaluates the residual at each of its trial steps."""
    found = {}
    for on in (True, False):
        system = _Lined("jump", at=0.7)
        line = _line(system)
        r0 = line(0.0)
        system.residuals = 0
        s = line_search(line, r0, NewtonOptions(secant_search=on))
        assert 0.6 < s < 0.7
        found[on] = system.residuals
    assert found[True] == 2
    assert found[False] > 2


def test_the_norm_tests_see_the_free_dofs_not_the_reactions():
    """A full step along which the free residual falls but the reaction on a prescribed
    DOF grows stands (the reaction is the load's, not an error); judged on the whole
    vector it was cut back to 1/64."""
    system = _Lined("kink", at=2.0, reaction=(5.0, 0.5))
    system.K = np.diag([0.3, 0.3, 0.3])           # g(1) = 0.7 g(0): not halved, descending
    line = _line(system)
    r0 = line(0.0)
    n0, n1 = np.linalg.norm(r0), np.linalg.norm(line(1.0))
    assert n1 > n0                                # the whole vector grew
    assert line_search(line, r0, NewtonOptions()) == 1.0


def test_secant_search_saves_residuals_and_reaches_the_same_state():
    """On the lip gesture's first 0.11 s (coarse half face, lip and teeth contact, where
    the lips close) the search on the secant model takes fewer whole residuals for the
    same lip outputs (to the Newton tolerance)."""
    runs = gesture_both_ways("secant_search", 0.11,
                             lambda sim: sim.face.model.system().counters["residuals"])
    (n0, rows0), (n1, rows1) = runs[False], runs[True]
    assert n1 < n0                   # 199 against 202 (BDF2; backward Euler: 245 against 267)
    assert_same_lips(rows0, rows1)


class _Spring:
    """One node on a unit spring to x = (1, 0, 0) (a load of 1 N)."""

    name, nonsmooth = "spring", False

    def blocks(self):
        return [np.array([[0]])]

    def load_scale(self, lam):
        return 1.0

    def assemble(self, state, asm, ids):
        x = state.u[0]
        asm.add_block(ids[0], (x - [1.0, 0.0, 0.0])[None, :], np.eye(3)[None])


class _Jump:
    """A force of 0.5 N against x that switches on at x_0 > 0.99 (no equilibrium: the
    residual jumps from -0.01 to +0.49 N there)."""

    name, nonsmooth = "jump", True

    def blocks(self):
        return [np.array([[0]])]

    def assemble(self, state, asm, ids):
        f = np.zeros((1, 3))
        f[0, 0] = 0.5 * (state.u[0, 0] > 0.99)
        asm.add_block(ids[0], f, np.zeros((1, 3, 3)))


def test_newton_stuck_at_a_jump_fails_at_once_not_after_the_stall_window():
    """From near the jump Newton's first search carries the node to it, where every
    direction's search ends at s ~ 0; two such searches in a row fail the call (the
    caller cuts back) instead of the stall test's eight iterations, naming the node
    where the residual jumps."""
    from solver.core.linsolve import SuperLU
    from solver.core.newton import newton
    from solver.core.system import System
    reports = {}
    for after in (2, 100):
        system = System([_Spring(), _Jump()], 1, [])
        u, _, rep = newton(system, np.array([0.98, 0.0, 0.0]), np.zeros(0), SuperLU(),
                           NewtonOptions(stuck_after=after))
        assert u is None
        reports[after] = rep
    assert reports[2].reason.startswith("stuck")
    assert "largest at node 0 (0.5 N)" in reports[2].reason     # where the force jumps
    assert reports[100].reason.startswith("stalled")
    assert reports[2].iterations <= 4 < 8 <= reports[100].iterations
