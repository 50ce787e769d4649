"""Cables, embedding and stiffening on small synthetic anatomies."""

import numpy as np
import pytest

import solver
from solver.face.activation import Activation
from solver.face.anatomy.base import MUSCLE_NAMES, Anatomy, Fibre
from solver.core.meshgen import box
from solver.face.muscles import MuscleProperties
from solver.core.system import System
from solver.face.terms.cables import Cables
from solver.face.terms.stiffening import Stiffening, muscle_neighbourhoods


def _anatomy(points, insertion=None, muscle="OOP"):
    mesh = box(4, 2, 2, (8.0, 4.0, 4.0))
    pts = np.asarray(points, dtype=float)
    ins = np.zeros(len(pts), bool) if insertion is None else np.asarray(insertion)
    return Anatomy("test", mesh, [Fibre(muscle, "left", pts, ins)], {})


def _cables(anatomy, a=0.0):
    act = Activation()
    act.set({"OOP": a})
    act.commit()
    return Cables(anatomy, ["OOP"], MuscleProperties(), act)


FIBRE = [[0.5, 1.3, 2.2], [3.1, 2.0, 1.7], [5.2, 2.9, 2.6], [7.5, 2.1, 1.9]]


@pytest.mark.parametrize("a", [0.0, 0.7])
def test_cable_tangent_matches_finite_differences(a, rng):
    anat = _anatomy(FIBRE, insertion=[True, False, False, False])
    cab = _cables(anat, a)
    sysm = System([cab], anat.mesh.n_nodes, [])
    u = (0.2 * anat.mesh.nodes).ravel() + 0.1 * rng.standard_normal(sysm.ndof)  # stretched
    r, data = sysm.assemble(u)
    assert np.all(cab.tension > 0)
    K = sysm.pattern.matrix(data).toarray()
    h = 1e-6
    dofs = np.unique(3 * cab.nodes.ravel()[:, None] + np.arange(3))
    Kn = np.zeros((sysm.ndof, len(dofs)))
    for k, d in enumerate(dofs):
        up, um = u.copy(), u.copy()
        up[d] += h
        um[d] -= h
        Kn[:, k] = (sysm.residual(up) - sysm.residual(um)) / (2 * h)
    assert np.abs(K[:, dofs] - Kn).max() <= 1e-6 * np.abs(K).max()


def test_peak_force_at_full_activation_and_rest_length():
    cab = _cables(_anatomy(FIBRE), 1.0)
    sysm = System([cab], 45, [])
    sysm.residual(np.zeros(sysm.ndof))
    assert np.allclose(cab.tension, MuscleProperties().f_max["OOP"])


def test_slack_cable_carries_no_force():
    anat = _anatomy(FIBRE)
    cab = _cables(anat, 0.3)
    sysm = System([cab], anat.mesh.n_nodes, [])
    # shorten everything by 40 %: beyond the active strain 0.3 * 0.5 = 0.15
    u = (-0.4 * anat.mesh.nodes).ravel()
    r = sysm.residual(u)
    assert np.all(cab.tension == 0.0) and np.all(r == 0.0)


def test_embedded_points_follow_their_host_bricks():
    anat = _anatomy(FIBRE, insertion=[True, False, False, False])
    cab = _cables(anat)
    A = np.array([[0.1, 0.02, 0.0], [-0.05, 0.2, 0.03], [0.0, 0.04, -0.1]])
    u = anat.mesh.nodes @ A.T
    x = cab.point_positions(u)
    X = cab.X
    expect = X + X @ A.T
    expect[0, 0] = X[0, 0]                      # the insertion stays on bone
    assert np.allclose(x, expect, atol=1e-12)


def test_inputs_are_checked_once_at_the_api_and_refused_by_name():
    """Simulation.set_inputs is the one place inputs are checked: a bad activation or jaw
    value raises ParameterError naming it, and nothing changes, not even the inputs that
    were good; an undriven muscle must stay at 0, or is left out with undriven "ignore"."""
    from solver.app.simulation import Simulation
    sim = Simulation("default", driven=("OOP", "RIS"))
    for bad in (float("nan"), float("inf"), -0.1, 1.5, "x"):
        with pytest.raises(solver.ParameterError, match="OOP"):
            sim.set_activations({"OOP": bad})
    with pytest.raises(solver.ParameterError, match="XYZ"):
        sim.set_activations({"XYZ": 0.5})
    sim.set_activations({"RIS": 0.2})
    with pytest.raises(solver.ParameterError):
        sim.set_activations({"RIS": 0.9, "OOP": float("nan")})     # all checked before any is set
    with pytest.raises(solver.ParameterError, match="jaw_opening = 25"):
        sim.set_inputs({"RIS": 0.9}, jaw=(25.0, 0.0))               # the jaw's too
    act = sim.face.activation
    assert act.target[MUSCLE_NAMES.index("RIS")] == 0.2 and sim.face.jaw.target[0] == 0.0
    with pytest.raises(solver.ParameterError, match="BUC is not driven"):
        sim.set_activations({"BUC": 0.5})
    assert sim.set_inputs({"BUC": 0.5, "OOP": 0.1}, undriven="ignore") == ["BUC"]
    with pytest.raises(solver.ParameterError, match="BUC"):
        sim.set_inputs({"BUC": float("nan")}, undriven="ignore")    # checked even if ignored
    assert act.target[MUSCLE_NAMES.index("OOP")] == 0.1
    assert act.target[MUSCLE_NAMES.index("BUC")] == 0.0


def test_a_step_commits_its_inputs_and_a_failed_one_rolls_them_back(monkeypatch):
    """Only the step commits: targets become the converged state after a step that
    converged, and go back to it after one that failed; no term commits them midway (here
    the held activation's substeps converge before a later one fails)."""
    import solver.core.transient as T
    from solver.app.simulation import Simulation
    from solver.core.newton import NewtonReport
    sim = Simulation("default", driven=("OOP",))
    oop = MUSCLE_NAMES.index("OOP")
    sim.set_activations({"OOP": 0.4})
    act = sim.face.activation
    assert act.start[oop] == 0.0                                # set: a target only
    assert sim.step(0.005).converged
    assert act.start[oop] == 0.4
    starts, real = [], T.newton

    def fails_third(*args, **kwargs):
        starts.append(act.start[oop])
        if len(starts) >= 3:
            return None, None, NewtonReport(False, 0, reason="made to fail")
        return real(*args, **kwargs)
    monkeypatch.setattr(T, "newton", fails_third)
    sim.integrator.hold, sim.integrator.max_cutbacks = "step", 0
    sim.set_activations({"OOP": 1.0})
    assert not sim.step(0.05).converged
    assert starts == [0.4] * len(starts) and len(starts) >= 3
    assert act.start[oop] == 0.4 == act.target[oop]


def test_stiffening_neighbourhood_and_factor():
    anat = _anatomy([[0.5, 2.0, 2.0], [7.5, 2.0, 2.0]])     # along x through the middle
    regions = muscle_neighbourhoods(anat, ["OOP"], {"OOP": 0.5})
    # the fibre runs along the shared edge of the 4 middle columns of bricks: all 16 bricks
    # touch it; a 0.5 mm sphere reaches no brick farther than 0.5 mm from the line
    cent = anat.mesh.nodes[anat.mesh.bricks].mean(axis=1)
    assert set(regions["OOP"]) == set(np.flatnonzero(np.abs(cent[:, 1] - 2) < 1.5))
    act = Activation()
    props = MuscleProperties()
    st = Stiffening(anat.mesh, np.tile(solver.MooneyRivlin().params, (16, 1)), regions,
                    props, act)
    assert np.all(st.factors(1.0) == 1.0)
    act.set({"OOP": 0.5})
    assert np.allclose(st.factors(1.0), 1 + 0.5 * (props.stiffening_max - 1))


@pytest.mark.parametrize("a", [0.0, 0.6])
def test_stiffening_in_the_tissues_pass_equals_its_own_pass(a, rng):
    """With the tissue's Elasticity as host the extra c10, c20 go into the tissue's kernel
    pass: residual, tangent and energy as with the stiffening's own pass over its bricks
    (isochoric, full F at the Gauss points), and the term has no blocks of its own."""
    from solver.core.terms.elasticity import Elasticity
    anat = _anatomy([[0.5, 1.0, 1.0], [7.5, 1.0, 1.0]])     # through one column of bricks
    mesh = anat.mesh
    regions = muscle_neighbourhoods(anat, ["OOP"], {"OOP": 0.5})
    params = np.tile(solver.MooneyRivlin().params, (mesh.n_bricks, 1))
    u = 0.3 * rng.standard_normal(3 * mesh.n_nodes)
    out = []
    for fused in (False, True):
        act = Activation()
        act.set({"OOP": a})
        el = Elasticity(mesh, params)
        st = Stiffening(mesh, params, regions, MuscleProperties(), act,
                        host=el if fused else None)
        assert (len(st.blocks()) == 0) == fused and 0 < len(regions["OOP"]) < mesh.n_bricks
        sysm = System([el, st], mesh.n_nodes, [])
        r, data = sysm.assemble(u)
        out.append((r, sysm.pattern.matrix(data).toarray(), sysm.energy))
        assert np.array_equal(el.params, params)            # the tissue's own unchanged
    (r0, k0, e0), (r1, k1, e1) = out
    assert np.allclose(r1, r0, rtol=0, atol=1e-12 * np.abs(r0).max())
    assert np.allclose(k1, k0, rtol=0, atol=1e-12 * np.abs(k0).max())
    assert e1 == pytest.approx(e0, rel=1e-12)
    plain = System([Elasticity(mesh, params)], mesh.n_nodes, []).residual(u)
    assert (np.abs(r1 - plain).max() > 1e-3 * np.abs(plain).max()) == (a > 0)


def test_stiffened_tissue_deforms_less_and_is_stiffer_transversely():
    """The paper's Eq. 2 argument: the transverse stiffness of an active region rises."""
    mesh = box(6, 2, 2, (12.0, 4.0, 4.0))
    fib = Fibre("OOP", "left", np.array([[0.0, 2.0, 2.0], [12.0, 2.0, 2.0]]),
                np.array([True, True]))
    anat = Anatomy("bar", mesh, [fib], {}, half=False)
    anat.mesh.node_sets["fixed"] = mesh.node_sets["xmin"]
    probe = np.intersect1d(mesh.node_sets["xmax"], mesh.node_sets["zmax"])

    def deflection(a, stiffening):
        face = solver.FaceModel(anat, muscles=("OOP",), stiffening=stiffening)
        face.model.fix(mesh.node_sets["xmax"], components=(0,))
        face.model.add_force(probe, (0.0, 0.0, -2e-4))
        face.set_activations({"OOP": a})
        res = face.solve_static()
        assert res.converged
        return -face.u[probe, 2].mean()

    d0, d1, dfree = deflection(0.0, True), deflection(1.0, True), deflection(1.0, False)
    assert d1 < 0.5 * d0                   # stiffness rises with activation
    assert d1 < dfree                      # and stiffening is what does it


@pytest.mark.parametrize("n", [4, 8])
def test_volume_rule_stiffens_the_tube_whatever_the_mesh(n):
    """Weighted by the volume fraction within r, the stiffened volume is the tube's
    pi r^2 L on a coarse and a fine mesh; the paper's whole-brick rule takes more, the
    more the coarser the mesh."""
    from solver.face.terms.stiffening import muscle_weights
    L, r = 8.0, 1.0
    mesh = box(n, n, n, (L, 4.0, 4.0))
    fib = Fibre("OOP", "left", np.array([[0.0, 2.1, 1.9], [L, 2.1, 1.9]]),
                np.array([False, False]))
    anat = Anatomy("bar", mesh, [fib], {}, half=False)
    regions = muscle_neighbourhoods(anat, ["OOP"], {"OOP": r})
    vol = mesh.det_j.sum(axis=1)[regions["OOP"]]            # brick volumes (8 Gauss pts, w = 1)
    tube = np.pi * r ** 2 * L
    w = muscle_weights(anat, regions, {"OOP": r}, "volume")["OOP"]
    assert abs((w * vol).sum() - tube) < 0.12 * tube
    whole = muscle_weights(anat, regions, {"OOP": r}, "intersect")["OOP"]
    assert (whole * vol).sum() > 1.3 * tube
