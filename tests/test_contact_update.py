"""Contact status changes as low-rank updates of a factorization (solver.core.contact_update):
the linearized penetrations against the contact terms' gaps and finite differences, the
corrected direction against the piecewise-linear model it solves, and Newton with and
without the update on two blocks pressed together.
"""

import numpy as np
import pytest
import scipy.sparse as sp

import solver
from solver.core.contact_update import ContactUpdate
from solver.core.linsolve import make_solver
from solver.core.meshgen import box
from solver.face.terms.contact import LipContact, RigidContact
from test_contact import STIFF, Runner, grid_surface, two_blocks
from conftest import REFERENCE_BALANCED


def _check_linear_gaps(term, n, u, rng, h=1e-5):
    Runner(term, n)(u, need_k=False)
    gap = term.gap.copy()
    dofs, v, k, p = term.linear_gaps(u)
    ok = np.isfinite(p)
    assert ok.sum() >= 4
    np.testing.assert_allclose(p[ok], -gap[ok], atol=1e-12)
    np.testing.assert_array_equal(k, term.k)
    du = rng.standard_normal(u.size) * h
    _, _, _, p2 = term.linear_gaps(u + du.reshape(-1, 3))
    _, _, _, p0 = term.linear_gaps(u - du.reshape(-1, 3))
    both = ok & np.isfinite(p2) & np.isfinite(p0)
    slope = (p2 - p0)[both] / 2
    np.testing.assert_allclose((v * du[dofs]).sum(axis=1)[both], slope, atol=1e-4 * h)


def test_rigid_linear_gaps_are_the_gaps_and_their_derivatives(rng):
    mesh = box(3, 3, 1, (4.0, 4.0, 2.0), origin=(-2.0, -2.0, 0.0))
    c, s = np.cos(0.3), np.sin(0.3)
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    term = RigidContact(mesh, mesh.node_sets["zmin"], grid_surface(6, 12.0, rotation=tilt))
    u = rng.uniform(-0.05, 0.05, (mesh.n_nodes, 3))             # some in, some out
    _check_linear_gaps(term, mesh.n_nodes, u, rng)


def test_lip_linear_gaps_are_the_gaps_and_their_derivatives_over_both_surfaces(rng):
    mesh, ida, idb, fa, fb = two_blocks(gap=0.0, rng=rng, jitter=0.02)
    term = LipContact(mesh, fb, fa)
    u = rng.uniform(-0.02, 0.02, (mesh.n_nodes, 3))
    _check_linear_gaps(term, mesh.n_nodes, u, rng)


def test_smoothed_laws_take_no_update():
    mesh = box(1, 1, 1, (2.0, 2.0, 1.0), origin=(-1.0, -1.0, 0.0))
    term = RigidContact(mesh, mesh.node_sets["zmin"], grid_surface(2, 8.0), smoothing=0.05)
    assert term.linear_gaps(np.zeros((mesh.n_nodes, 3))) is None


class _Slaves:
    """A contact term stand-in: slaves with fixed dofs, v, k, p."""

    def __init__(self, dofs, v, k, p):
        self.data = (dofs, v, k, p)

    def linear_gaps(self, u):
        return self.data


class _System:
    def __init__(self, terms, ndof, free):
        self.terms, self.ndof, self.free = terms, ndof, free


@pytest.mark.parametrize("reused", [False, True])
def test_corrected_direction_solves_the_model_of_its_own_predicted_status(rng, reused):
    n = 60
    B = sp.random(n, n, 0.08, random_state=3)
    A = 0.2 * B @ B.T + sp.eye(n)                    # weakly coupled: the status settles
    free = np.arange(3, n + 3)                       # the first 3 DOFs are prescribed
    s = 6
    dofs = 3 * (1 + 2 * np.arange(s))[:, None] + np.arange(3)       # nodes 1, 3, ..., 11
    v = rng.standard_normal((s, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    k = rng.uniform(5.0, 20.0, s)
    p_mark = np.array([0.01, 0.02, -0.001, -0.002, 0.005, -0.01])  # three in contact
    term = _Slaves(dofs, v, k, p_mark)
    cu = ContactUpdate(_System([term], n + 3, free))
    index = -np.ones(n + 3, dtype=int)
    index[free] = np.arange(n)

    def column(i, vec=v):
        ui = np.zeros(n)
        f = index[dofs[i]]
        ui[f[f >= 0]] = vec[i][f >= 0]
        return ui

    A = A.toarray()
    for i in np.flatnonzero(p_mark >= 0):            # the tangent holds the active slaves
        A += k[i] * np.outer(column(i), column(i))
    lin = make_solver("superlu")
    lin.refactor(sp.csr_matrix(A), "tag")
    cu.mark(lin, np.zeros(n + 3))
    # a later iterate on the same factorization: slave 2 came in, slave 4 left, and every
    # gradient turned (a slave that leaves must take out the stiffness A holds: its
    # gradient at the mark, not the one now)
    p, v_now = p_mark, v
    if reused:
        p = p_mark + np.array([0.0, 0.0, 0.003, 0.0, -0.008, 0.0])
        v_now = v + 0.3 * rng.standard_normal((s, 3))
        v_now /= np.linalg.norm(v_now, axis=1)[:, None]
    term.data = (dofs, v_now, k, p)
    # a residual with the forces of the active slaves, pulling the first two out and
    # pushing the third and fourth in
    r = np.zeros(n + 3)
    for i in np.flatnonzero(p >= 0):
        r[dofs[i]] += k[i] * p[i] * v_now[i]
    for i, sign in ((0, 1.0), (1, 1.0), (2, -1.0), (3, -1.0)):
        r[dofs[i]] += sign * 2.0 * v_now[i]
    du = np.zeros(n + 3)
    du[free] = lin.solve(-r[free])
    out = cu.correct(lin, np.zeros(n + 3), du)
    assert cu.settled and cu.corrections > 0
    want = p + (v_now * out[dofs]).sum(axis=1) > 0
    mat = np.flatnonzero(want != (p_mark >= 0))
    rhs = np.flatnonzero(want != (p >= 0))
    assert sorted(cu.changed) == [((0, i, int(want[i])), bool(want[i])) for i in mat]
    assert reused == (list(mat) != list(rhs))
    # (A + sum_mat D u u^T) du = -r - sum_rhs D p u on the free DOFs, with u the gradient
    # at the mark for a slave that leaves and the one now for a slave that comes in
    M, b = A.copy(), -r[free]
    for i in mat:
        ui = column(i, v_now if want[i] else v)
        M += (k[i] if want[i] else -k[i]) * np.outer(ui, ui)
    for i in rhs:
        b -= (k[i] if want[i] else -k[i]) * p[i] * column(i, v_now)
    np.testing.assert_allclose(M @ out[free], b, atol=1e-9 * np.abs(b).max())
    np.testing.assert_array_equal(out[:3], 0.0)


def test_a_singular_model_leaves_the_direction_alone():
    # the slave carries all the stiffness of DOF 0: dropping it leaves nothing there
    term = _Slaves(np.array([[0, 1, 2]]), np.array([[1.0, 0.0, 0.0]]), np.array([2.0]),
                   np.array([0.1]))
    cu = ContactUpdate(_System([term], 3, np.arange(3)))
    lin = make_solver("superlu")
    lin.refactor(sp.diags([2.0, 1.0, 1.0], format="csr"), "tag")
    cu.mark(lin, np.zeros(3))
    du = np.array([-0.5, 0.0, 0.0])                   # pulled out: p + v . du < 0
    assert cu.correct(lin, np.zeros(3), du) is du and cu.changed == []


def test_no_recorded_status_leaves_the_direction_alone(rng):
    system = _System([_Slaves(np.array([[0, 1, 2]]), np.ones((1, 3)), np.ones(1),
                              np.array([-0.1]))], 3, np.arange(3))
    lin = make_solver("superlu")
    lin.refactor(sp.eye(3, format="csr"), "tag")          # not marked
    du = rng.standard_normal(3)
    assert ContactUpdate(system).correct(lin, np.zeros(3), du) is du


@pytest.mark.parametrize("solver_name", ["superlu", "pardiso"])
def test_newton_with_the_update_reaches_the_same_contact_state(solver_name):
    if solver_name not in solver.core.linsolve.available():
        pytest.skip("pardiso not installed")
    results = {}
    for update in (False, True):
        mesh, ida, idb, fa, fb = two_blocks()
        term = LipContact(mesh, fb, fa)
        model = solver.Model(mesh, STIFF, linear_solver=solver_name)
        model.fix(mesh.node_sets["A_zmin"])
        model.fix(mesh.node_sets["B_xmin"], components=(0,))
        model.fix(mesh.node_sets["B_ymin"], components=(1,))
        top = mesh.node_sets["B_zmax"]
        model.add_force(top, np.outer(np.full(len(top), 1.0 / len(top)), [0.0, 0.0, -1.0]))
        model.add_term(term)
        model.newton_options.contact_update = update
        res = model.solve_static(steps=2)
        assert res.converged
        results[update] = (res.displacement, term.n_active)
    (u0, n0), (u1, n1) = results[False], results[True]
    np.testing.assert_allclose(u1, u0, atol=1e-6)
    assert n1 == n0 >= 10


def test_lip_gesture_takes_fewer_factorizations_with_the_update():
    from solver.app.gestures import gesture
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation

    runs = {}
    for update in (False, True):
        sim = Simulation(parse_scene(gesture(0.03)), level="coarse", half=True,
                         **REFERENCE_BALANCED)
        sim.face.model.newton_options.contact_update = update
        its, rows = [0], []

        def record(s, row):
            rows.append(row)
            if s.t > 0:
                its[0] += s.last.newton_iterations
        sim.run(on_record=record)
        runs[update] = (sim.face.model.linear_solver.factorizations, its[0], rows)
        sim.release()
    (f0, it0, rows0), (f1, it1, rows1) = runs[False], runs[True]
    # a third of the factorizations; the predicted contact set is sometimes wrong on the
    # lips' subdivided faces, which costs a few iterations more
    assert f1 < 0.85 * f0 and it1 <= 1.2 * it0
    for a, b in zip(rows0, rows1):
        assert abs(a["lip_protrusion"] - b["lip_protrusion"]) < 1e-4
        assert abs(a["lip_aperture"] - b["lip_aperture"]) < 1e-4
