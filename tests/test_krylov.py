"""Newton directions by GMRES on a reused factorization (solver.core.krylov)."""

import numpy as np
import scipy.sparse as sp
from conftest import assert_same_lips, gesture_both_ways

from solver.core.krylov import gmres
from solver.core.linsolve import SuperLU


def _spd(n, rng):
    B = sp.random(n, n, density=0.02, random_state=rng)
    return (B @ B.T + sp.eye(n) * n * 0.05).tocsr()


def _low_rank(n, rng, rank, scale):
    """A symmetric perturbation on a few DOFs, as a contact's change of tangent."""
    dofs = rng.choice(n, size=3 * rank, replace=False)
    W = sp.csr_matrix((rng.standard_normal(3 * rank), (dofs, np.repeat(np.arange(rank), 3))),
                      shape=(n, rank))
    return (scale * (W @ W.T)).tocsr()


def _factorized(n, rng, rank, scale):
    """(A, D, solver factorized with A, c, A^-1 c): an SPD A, a low-rank D, a random c."""
    A, D = _spd(n, rng), _low_rank(n, rng, rank, scale)
    lin = SuperLU()
    lin.refactor(A, "t")
    c = rng.standard_normal(n)
    return A, D, lin, c, lin.solve(c)


def test_gmres_solves_the_perturbed_system_with_the_factorizations_solves(rng):
    """(A + D) du = c to the tolerance from A's solves alone, in few iterations for a
    low-rank D, and A du kept consistent with du."""
    A, D, lin, c, du0 = _factorized(300, rng, 4, 50.0)
    du, Adu, solves, _ = gmres(lin.solve, D, c, du0, c.copy(), 1e-8, 30)
    exact = sp.linalg.spsolve((A + D).tocsc(), c)
    assert np.linalg.norm((A + D) @ du - c) <= 1e-7 * np.linalg.norm(c)
    assert np.allclose(du, exact, rtol=0, atol=1e-6 * np.abs(exact).max())
    assert np.allclose(Adu, A @ du, atol=1e-8 * np.abs(Adu).max())
    assert 0 < solves <= 6                        # rank(D) + 1 in exact arithmetic
    plain = np.linalg.norm((A + D) @ du0 - c)     # the modified Newton step's residual
    assert plain > 1e3 * np.linalg.norm((A + D) @ du - c)


def test_gmres_gives_up_within_its_budget_and_keeps_a_good_start(rng):
    """A start that already meets the tolerance costs no solve; a budget too small for the
    tolerance returns no direction (Newton then refactorizes)."""
    A, D, lin, c, du0 = _factorized(200, rng, 10, 100.0)
    assert gmres(lin.solve, D, c, du0, c.copy(), 1e-12, 2)[0] is None
    du, _, _, _ = gmres(lin.solve, D, c, du0, c.copy(), 1e-10, 60)
    again = gmres(lin.solve, D, c, du, (A @ du), 1e-8, 5)
    assert again[2] == 0 and again[0] is du


def test_recycled_directions_solve_a_nearby_system_with_fewer_solves(rng):
    """The directions solved for one change D (with A Z kept) span most of what a nearby
    change needs: with them the next solve needs fewer new solves, to the same answer
    (GCRO augmentation)."""
    n = 300
    A, D = _spd(n, rng), _low_rank(n, rng, 6, 50.0)
    D2 = D + 0.05 * _low_rank(n, rng, 2, 50.0)
    lin = SuperLU()
    lin.refactor(A, "t")
    c, c2 = rng.standard_normal(n), rng.standard_normal(n)
    _, _, _, kept = gmres(lin.solve, D, c, lin.solve(c), c.copy(), 1e-8, 40)
    assert len(kept[0]) > 0 and np.allclose(A @ kept[0].T, kept[1].T, atol=1e-9)
    du2 = lin.solve(c2)
    plain = gmres(lin.solve, D2, c2, du2, c2.copy(), 1e-6, 40)
    again = gmres(lin.solve, D2, c2, du2, c2.copy(), 1e-6, 40, recycled=kept)
    for du, _, _, _ in (plain, again):
        assert np.linalg.norm((A + D2) @ du - c2) <= 1e-6 * np.linalg.norm(c2) * 1.0001
    assert again[2] < plain[2]


def test_krylov_directions_save_factorizations_and_reach_the_same_state():
    """On the lip gesture's first 0.05 s (coarse half face, lip and teeth contact) GMRES
    directions with the contact's current tangent replace some refactorizations of the
    modified Newton (at the price of solves, and of line searches along them); the lip
    outputs are those of the plain reuse to the Newton tolerance."""
    runs = gesture_both_ways("krylov", 0.05,
                             lambda sim: sim.face.model.linear_solver.factorizations)
    (f0, rows0), (f1, rows1) = runs[False], runs[True]
    assert f1 < 0.9 * f0
    assert_same_lips(rows0, rows1)
