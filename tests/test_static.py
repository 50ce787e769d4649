"""Static solves: patch test, analytic homogeneous cases, volume, Newton, locking."""

import numpy as np
import pytest
from scipy.optimize import brentq

import solver
from solver.core.kernels.material_point import response
from solver.core.meshgen import box


def _uniaxial_model(stretch, n=3, L=10.0, material=None):
    mesh = box(n, n, n, (L, L, L))
    model = solver.Model(mesh, material or solver.MooneyRivlin())
    model.fix(mesh.node_sets["xmin"], components=(0,))
    model.fix(mesh.node_sets["ymin"], components=(1,))
    model.fix(mesh.node_sets["zmin"], components=(2,))
    model.prescribe(mesh.node_sets["zmax"], displacement=(0, 0, (stretch - 1) * L),
                    components=(2,))
    return mesh, model


def _analytic_nominal_stress(stretch, p):
    """P_33 of this energy in uniaxial stress: lateral stretch from P_11 = 0."""
    lat = brentq(lambda l: response(np.diag([l, l, stretch]), p)[1][0, 0], 0.3, 2.0)
    return response(np.diag([lat, lat, stretch]), p)[1][2, 2], lat


@pytest.mark.parametrize("stretch", [1.5, 0.7])
def test_uniaxial_nominal_stress_matches_analytic(stretch):
    L = 10.0
    mesh, model = _uniaxial_model(stretch, L=L)
    res = model.solve_static()
    assert res.converged
    force = res.reaction(mesh.node_sets["zmax"])[2]
    P33, lat = _analytic_nominal_stress(stretch, solver.MooneyRivlin().params)
    assert force / L**2 == pytest.approx(P33, rel=5e-3)
    assert 1 + res.displacement[mesh.node_sets["xmax"], 0].mean() / L == pytest.approx(lat, rel=5e-3)


def test_patch_test_linear_field_reproduced_inside_a_distorted_patch(rng):
    mesh0 = box(3, 3, 3, (3.0, 3.0, 3.0))
    X = mesh0.nodes.copy()
    inner = np.flatnonzero(np.all((X > 0.5) & (X < 2.5), axis=1))
    X[inner] += rng.uniform(-0.3, 0.3, (len(inner), 3))
    mesh = solver.Mesh(X, mesh0.bricks)
    boundary = np.setdiff1d(np.arange(mesh.n_nodes), inner)
    A = np.array([[0.10, 0.05, -0.02], [0.03, -0.08, 0.04], [-0.05, 0.02, 0.12]])
    model = solver.Model(mesh)
    model.prescribe(boundary, displacement=X[boundary] @ A.T)
    res = model.solve_static()
    assert res.converged
    assert np.abs(res.displacement[inner] - X[inner] @ A.T).max() < 1e-8


def test_volume_is_preserved_under_30_percent_compression():
    L = 10.0
    mesh = box(4, 4, 4, (L, L, L))
    model = solver.Model(mesh)
    model.fix(mesh.node_sets["zmin"])                   # bonded ends: barrelling
    model.prescribe(mesh.node_sets["zmax"], displacement=(0, 0, -0.3 * L))
    res = model.solve_static(steps=3)
    assert res.converged
    deformed = solver.Mesh(mesh.nodes + res.displacement, mesh.bricks)
    bulge = res.displacement[mesh.node_sets["xmax"], 0].max()
    assert bulge > 1.0                                   # it did barrel
    assert abs(deformed.volumes.sum() / mesh.volumes.sum() - 1) < 5e-3


def test_newton_converges_quadratically():
    _, model = _uniaxial_model(1.4)
    model.newton_options.rtol = 1e-13
    res = model.solve_static()
    r = np.array(res.steps[-1]["residuals"][1:])        # [0]: the start, before the predictor
    e = r / r[0]
    # near the solution (e_k < 1e-2), above round-off (e_k+1 > 1e-11), the exponent doubles
    near = [(a, b) for a, b in zip(e[:-1], e[1:]) if a < 1e-2 and b > 1e-11]
    assert near, e
    assert all(np.log(b) / np.log(a) > 1.8 for a, b in near), e


def test_reactions_balance_applied_force():
    mesh = box(2, 2, 4, (2.0, 2.0, 8.0))
    model = solver.Model(mesh)
    model.fix(mesh.node_sets["zmin"])
    top = mesh.node_sets["zmax"]
    model.add_force(top, (1e-4, 0.0, -2e-4))
    res = model.solve_static()
    assert res.converged
    assert np.allclose(res.reaction(mesh.node_sets["zmin"]),
                       -len(top) * np.array([1e-4, 0.0, -2e-4]), atol=1e-10)


def test_hard_step_is_cut_back_and_reported():
    _, model = _uniaxial_model(0.4)
    model.newton_options.max_iter = 4
    res = model.solve_static()
    assert res.converged and res.cutbacks > 0
    assert len(res.steps) > 1 and not all(s["converged"] for s in res.steps)


def test_failed_solve_leaves_the_state_unchanged():
    mesh, model = _uniaxial_model(1.2)
    assert model.solve_static().converged
    before = model.u.copy()
    model.prescribe(mesh.node_sets["zmax"], displacement=(0, 0, -15.0), components=(2,))
    res = model.solve_static(max_cutbacks=3)              # through zero thickness: impossible
    assert not res.converged and res.reason
    assert np.array_equal(model.u, before)


def _cook_tip(n, formulation):
    """Cook's membrane in plane strain, nu = 0.499, small tip shear: tip deflection (mm)."""
    def trapezoid(p):
        s, t = p[:, 0], p[:, 1]
        return np.column_stack([48 * s, (1 - t) * 44 * s + t * (44 + 16 * s), p[:, 2]])
    mesh = box(n, n, 1, mapping=trapezoid)
    model = solver.Model(mesh, solver.MooneyRivlin.from_poisson(2.5e-3, 0.499),
                         formulation=formulation)
    model.fix(mesh.node_sets["xmin"])
    model.fix(np.arange(mesh.n_nodes), components=(2,))
    right = mesh.node_sets["xmax"]
    y = mesh.nodes[right, 1]
    # uniform shear traction on the right edge, lumped by tributary length per z layer
    w = np.zeros(len(right))
    for z in (0.0, 1.0):
        idx = np.flatnonzero(np.isclose(mesh.nodes[right, 2], z))
        idx = idx[np.argsort(y[idx])]
        d = np.diff(y[idx])
        w[idx[:-1]] += d / 2
        w[idx[1:]] += d / 2
    model.add_force(right, np.outer(1e-4 * w / w.sum(), [0.0, 1.0, 0.0]))
    res = model.solve_static()
    assert res.converged
    return res.displacement[right[np.argmax(y)], 1]


@pytest.mark.parametrize("formulation,locks", [("mean_dilatation", False), ("full", True)])
def test_no_locking_in_bending_at_nu_0499(formulation, locks):
    """16 x 16 within 2 % of 32 x 32 for the mean-dilatation brick; the plain brick fails."""
    coarse, fine = _cook_tip(16, formulation), _cook_tip(32, formulation)
    assert (abs(coarse / fine - 1) > 0.02) == locks


def test_a_load_step_that_creeps_on_in_ever_smaller_steps_fails_with_a_reason(monkeypatch):
    """Steps that succeed and fail in turn (a residual jump no smaller step crosses) shrink
    the increment without a run of cutbacks: the solve must fail, not loop forever."""
    import solver.core.model as model_module
    from solver.core.newton import NewtonReport

    _, model = _uniaxial_model(1.2)
    before = model.u.copy()
    calls, state = [], {"lam": 0.0, "allowed": 0.1}

    def alternating_newton(sysm, u, targets, linear_solver, opts):
        # converges only for steps no larger than `allowed`, which halves at each success
        calls.append(sysm.lam)
        if len(calls) > 5000:
            raise RuntimeError("the load stepper did not stop")
        if sysm.lam - state["lam"] <= state["allowed"]:
            state["lam"], state["allowed"] = sysm.lam, state["allowed"] / 2
            return u, 0.0, NewtonReport(True, 1, [0.0], "")
        return None, None, NewtonReport(False, 3, [1.0], "residual jump")

    monkeypatch.setattr(model_module, "newton", alternating_newton)
    res = model.solve_static(min_increment=1e-4)
    assert not res.converged
    assert "increment fell below" in res.reason and "residual jump" in res.reason
    assert len(calls) < 200
    assert np.array_equal(model.u, before)


def test_a_load_stepping_that_crawls_is_failed_with_the_state_restored():
    """A large bending of a soft block takes tens of load steps; bounded to fewer, the
    solve fails naming the crawl, with the displacements as they were."""
    mesh = box(2, 2, 4, (2.0, 2.0, 8.0))
    model = solver.Model(mesh)
    model.fix(mesh.node_sets["zmin"])
    model.add_force(mesh.node_sets["zmax"], (1e-4, 0.0, -2e-4))
    before = model.u.copy()
    res = model.solve_static(max_steps=8)
    assert not res.converged and "load stepping crawls" in res.reason, res.reason
    assert len(res.steps) == 8
    assert np.array_equal(model.u, before)
    res = model.solve_static()                       # the default bound lets it through
    assert res.converged and len(res.steps) > 8
    assert np.abs(model.u).max() > 5.0


def test_damped_relaxation_reaches_the_load_stepped_equilibrium():
    """Where load-stepped Newton converges, the damped relaxation (solver.core.transient.relax)
    ends at the same equilibrium, to Newton's tolerance, and leaves no damping term."""
    from solver.core.transient import relax
    mesh = box(2, 2, 4, (2.0, 2.0, 8.0))
    results = []
    for how in ("newton", "relax"):
        model = solver.Model(mesh)
        model.fix(mesh.node_sets["zmin"])
        model.add_force(mesh.node_sets["zmax"], (2e-4, 0.0, -2e-4))
        n_terms = len(model.terms)
        if how == "newton":
            assert model.solve_static().converged
        else:
            rel = relax(model)
            assert rel.converged and rel.pseudo_time > 0 and rel.substeps > 0, rel
            assert len(model.terms) == n_terms
        results.append(model.u.copy())
    assert np.abs(results[0]).max() > 0.1
    assert np.allclose(results[0], results[1], atol=1e-4)


def test_relaxation_without_an_equilibrium_fails_and_leaves_the_state_unchanged():
    """A free block under a force has no static equilibrium: the damped block drifts,
    the undamped Newton fails, and after t_max the model is back where it started."""
    from solver.core.transient import relax
    mesh = box(1, 1, 1, (2.0, 2.0, 2.0))
    model = solver.Model(mesh)
    model.add_force(np.arange(mesh.n_nodes), (0.0, 0.0, 1e-4))
    before = model.u.copy()
    terms = list(model.terms)
    rel = relax(model, t_max=0.3)
    assert not rel.converged and "no static equilibrium" in rel.reason
    assert np.array_equal(model.u, before) and model.terms == terms


def test_a_model_with_every_node_prescribed_solves_to_its_targets_or_refuses_inversion():
    """No free DOF: the state is the targets, the residual the reactions (no linear solve);
    a prescription that inverts the brick is refused with the state kept."""
    X = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
    m = solver.Model(solver.Mesh(X, np.array([[0, 1, 3, 2, 4, 5, 7, 6]])),
                     solver.MooneyRivlin(c10=2.5e-3, d=0.8))
    m.fix([0, 1, 2, 3])
    m.prescribe([4, 5, 6, 7], displacement=(0, 0, 0.1))
    res = m.solve_static()
    assert res.converged and res.iterations == 0
    np.testing.assert_array_equal(m.u[4:], [[0, 0, 0.1]] * 4)
    m.prescribe([4, 5, 6, 7], displacement=(0, 0, -1.5))     # through the bottom face
    res = m.solve_static()
    assert not res.converged and "det F" in res.reason
    np.testing.assert_array_equal(m.u[4:], [[0, 0, 0.1]] * 4)
