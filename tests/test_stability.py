"""Hard cases stay stable: the quick versions of the cases of solver/validation/stability/
(the full ones run with `python benchmarks/stress.py`, or here with `pytest -m slow`).

For every case: no NaN or inf, no inverted brick (det F > 0 at every Gauss point), lips
within the contact tolerance where contact is on, outputs within bounds (aperture >= 0),
dissipated energy never decreasing, statistics (cutbacks) reported; a step that cannot be
taken is refused with the state unchanged. Halving every substep changes the outputs by
less than halving_limit (0.05 mm + 2 % of the motion at the default substep
tolerance; sqrt(tol / 1e-3) times the 0.05 mm at a looser one). The same cases through the built
FMU give the same outputs.
The checks themselves are shown to catch broken states.
"""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from solver.validation import stability as S
from solver.face.anatomy.base import MUSCLE_NAMES
from solver.face.face_model import LIP_OUTPUTS
from solver.app.simulation import Simulation
from solver.core.transient import StepStats
from conftest import SCRIPTS

QUICK = {c.name: c for c in S.cases(full=False)}
_runs = {}


def quick_run(name):
    """The quick case's run in this process (once per session)."""
    if name not in _runs:
        _runs[name] = S.run_case(QUICK[name])
    return _runs[name]


def _explain(run):
    return "\n".join(run.problems)


# In the default suite: the cases CI must cover through the FMU (the all-muscles step, the
# bang-bang, the pressed-then-released lips: test_quick_cases_through_the_fmu, which compares
# each with its run here), one random switching schedule, and the rest but these, which
# benchmarks/stress.py runs in full and `pytest -m slow` runs here: the jaw at 10 Hz (the
# jaw's rollback and refusals go through the FMU in tests/test_fmu.py), rest at 1 ms steps
# (nothing moves) and two more random switching schedules.
BENCHMARK_ONLY = ("jaw_10hz_pressed", "rest_1ms_steps", "switching_1", "switching_2")


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow)
                                  if n in BENCHMARK_ONLY else n for n in QUICK])
def test_quick_case_keeps_every_invariant(name):
    run = quick_run(name)
    assert run.passed, _explain(run)
    case = QUICK[name]
    assert run.steps == len(case.steps) - len(case.refused)
    assert run.refused == list(case.refused)
    assert run.min_det_f > 0 and np.isfinite(run.min_det_f)
    if not case.rest:
        assert run.dissipated > 0.0                   # the face moved, damping took energy
    assert run.rollbacks == case.rollback             # every rolled-back repeat the same
    if name == "oop_buc_contact":                      # the lips do meet: contact is exercised
        assert 0 < run.lip_penetration <= S.CONTACT_TOLERANCE
        assert 0 < run.teeth_penetration <= S.CONTACT_TOLERANCE


def test_halving_every_substep_changes_the_outputs_little():
    case = QUICK["huge_steps"]
    run = quick_run("huge_steps")
    half = S.run_case(case.halved(), probe=False)
    assert half.passed, _explain(half)
    assert 1.6 < half.substeps / run.substeps < 2.6            # the substeps did halve
    change = S.halving_change(run, half)
    assert run.substep_tol == 1e-3                  # the case's scene: the default tolerance
    assert 0 < change <= S.halving_limit(run)


def test_the_halving_limit_grows_as_the_square_root_of_the_substep_tolerance():
    """0.05 mm + 2 % of the excursion at the default tolerance and below, sqrt(tol / 1e-3)
    times the 0.05 mm above it; a reduced run (no adaptive tolerance) gets the constant."""
    run = S.CaseRun("x", start={k: 0.0 for k in LIP_OUTPUTS},
                    rows=[{k: (2.0 if k == "lip_aperture" else 0.0) for k in LIP_OUTPUTS}])
    for tol, expected in ((None, 0.05), (1e-4, 0.05), (1e-3, 0.05), (4e-3, 0.1),
                          (5e-2, 0.05 * 50 ** 0.5)):
        run.substep_tol = tol
        assert S.halving_limit(run) == pytest.approx(expected + 0.02 * 2.0, rel=1e-12)


def test_quick_cases_through_the_fmu(fmu, tmp_path):
    import subprocess
    import sys
    # the others run in this process (test_quick_case_keeps_every_invariant) and through
    # the FMU in benchmarks/stress.py; three random schedules go through the FMU in
    # test_randomized_campaign_through_the_fmu_a_few_seeds, the jaw in
    # tests/test_fmu.py::test_the_jaw_through_the_fmu_opens_rolls_back_exactly_and_refuses_bad_values
    names = ["all_muscles_step", "bang_bang_20hz", "pressed_released", "rollback_pressed",
             "refusal"]
    specs = [S.fmu_spec(QUICK[n], tmp_path / f"{n}.toml") for n in names]
    (tmp_path / "cases.json").write_text(json.dumps(specs))
    proc = subprocess.run([sys.executable, str(SCRIPTS / "stress_case.py"), str(fmu),
                           str(tmp_path / "out.json"), str(tmp_path / "cases.json")],
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert "ok" in proc.stdout.splitlines(), proc.stdout[-2000:] + proc.stderr[-4000:]
    results = json.loads((tmp_path / "out.json").read_text())
    from solver.face.anatomy.load import load_anatomy
    bounds = S.output_bounds(load_anatomy("generic", "coarse", True))
    for n in names:
        problems, m = S.check_fmu_run(QUICK[n], results[n], quick_run(n), bounds)
        assert not problems, (n, problems)
        assert m["fmu_vs_solver"] <= S.FMU_MATCH_TOLERANCE
    assert results["refusal"]["statuses"] == [0, 2, 0]
    assert results["rollback_pressed"]["rollback"]["repeats"] == QUICK["rollback_pressed"].rollback
    assert "did not converge" in proc.stdout                 # the refusal was logged
    assert proc.returncode == 0, proc.stderr[-3000:]         # and the process exits cleanly


@pytest.mark.parametrize("scene,fidelity,steps", [
    ("oop_buc_contact", "", 20),
    ("default", "", 20),
    pytest.param("default", "balanced", 20, marks=pytest.mark.slow)])
def test_lips_stay_out_of_each_other_under_oop_and_buc(scene, fidelity, steps):
    """OOP + BUC at 1 in 5 ms steps for the first 0.1 s (where the stress case's lip
    corner went 0.094 mm into the upper lip at 0.095 s), with lip and teeth contact, in the
    stress case's scene and the default scene with all ten muscles (at `balanced` too:
    slow, as the stress run's balanced part covers it): after every step no lip node is
    inside the other lip or behind the teeth by more than the contact tolerance, measured
    outside the model (solver.validation.stability.Probe: depths behind the bilinear faces)."""
    from solver.app.scene import parse_scene
    if scene == "oop_buc_contact":
        scene = parse_scene(QUICK[scene].scene)
    sim = Simulation(scene, fidelity=fidelity or None)
    probe = S.Probe(sim.anatomy)
    sim.set_activations({"OOP": 1.0, "BUC": 1.0})
    depths = []
    for k in range(steps):
        assert sim.step((k + 1) * 0.005).converged
        depths.append(probe.penetrations(sim.face.u))
    assert sim.outputs()["lip_protrusion"] != 0.0
    lips, teeth = np.max(depths, axis=0)
    assert teeth <= S.CONTACT_TOLERANCE, depths
    assert lips <= S.CONTACT_TOLERANCE, depths


# ------------------------------------------------------------- the checks can fail

@pytest.fixture(scope="module")
def sim():
    return Simulation("no_contact")


@pytest.fixture(scope="module")
def probe(sim):
    return S.Probe(sim.anatomy)


@pytest.fixture
def fresh(sim):
    start = sim.get_state()
    sim.integrator.dissipated = 0.0
    yield sim
    sim.set_state(start)


def test_an_fmu_that_fails_to_initialize_is_a_problem_not_a_pass():
    """A case whose FMU instance could not leave initialization (stress_case.py records
    init_status, e.g. a realtime fidelity with no trained model) fails the FMU check."""
    case = S.cases()[0]
    found, measures = S.check_fmu_run(case, {"rows": [], "statuses": [], "memory": {},
                                             "rollback": {}, "wall": 0.0, "init_status": 4})
    assert found == ["initialization failed with status 4"]
    assert np.isnan(measures["fmu_vs_solver"])
    ok, _ = S.check_fmu_run(case, {"rows": [], "statuses": [], "memory": {},
                                   "rollback": {}, "wall": 0.0})
    assert "initialization failed with status 4" not in ok


def test_checks_catch_nan_inversion_penetration_and_bounds(fresh, probe):
    measures, problems = S.check_state(fresh, probe)
    assert problems == [] and measures["min_det_f"] == pytest.approx(1.0)
    nodes = fresh.anatomy.mesh.nodes
    fresh.face.model.u = np.full_like(nodes, np.nan)
    assert any("non-finite" in p for p in S.check_state(fresh, probe)[1])
    fresh.face.model.u = -2.0 * nodes                         # F = -I: every brick inverted
    measures, problems = S.check_state(fresh, probe)
    assert measures["min_det_f"] == pytest.approx(-1.0)
    assert any("inverted brick" in p for p in problems)
    u = np.zeros_like(nodes)
    u[:, 1] = 500.0                                           # the face 0.5 m forward
    fresh.face.model.u = u
    assert any("lip_protrusion" in p for p in S.check_state(fresh, probe)[1])
    # the upper lip pushed 3 mm down into the lower lip: seen, and refused with contact on
    lm = fresh.anatomy.landmarks
    upper = np.unique(fresh.anatomy.contact_surfaces["upper_lip"])
    lower = np.unique(fresh.anatomy.contact_surfaces["lower_lip"])
    gap = nodes[lm["upper_lip_edge"], 2] - nodes[lm["lower_lip_edge"], 2]
    u = np.zeros_like(nodes)
    u[np.setdiff1d(upper, lower), 2] = -(gap + 1.0)
    fresh.face.model.u = u
    lips, _ = probe.penetrations(u)
    assert lips > S.CONTACT_TOLERANCE
    assert {n for n, _, _ in probe.inside} & set(upper.tolist())    # upper-lip nodes inside
    assert not any("penetration" in p for p in S.check_state(fresh, probe)[1])  # contact off
    contact = Simulation("default", loaded_anatomy=fresh.anatomy)
    contact.face.model.u = u
    assert any("lip penetration" in p for p in S.check_state(contact, probe)[1])


def test_point_triangle_distance_against_sampling(rng):
    a, b, c = rng.normal(size=(3, 50, 3))
    u, v = np.meshgrid(np.linspace(0, 1, 81), np.linspace(0, 1, 81))
    keep = u + v <= 1
    for p in rng.normal(scale=2.0, size=(10, 3)):
        d = S.point_triangle_distance(p, a, b, c)
        pts = a[:, None] + u[keep][None, :, None] * (b - a)[:, None] \
            + v[keep][None, :, None] * (c - a)[:, None]
        sampled = np.linalg.norm(pts - p, axis=2).min(axis=1)
        assert np.all(d <= sampled + 1e-12) and np.all(sampled - d < 0.1)


def test_probe_sees_a_node_inside_a_brick_only_where_it_is(rng):
    """A lip-corner node beside a distorted upper-lip brick (generic coarse face, a
    random switching case at t = 0.18 s): Newton on the trilinear map, started at the
    brick's centre and clipped, stops inside the reference cube 6.3 mm from the node
    (no root: the node is outside, winding number 0); the probe once counted it as
    2.57 mm deep. The brick's own points and its centroid are inside; points pushed out
    of a face are not."""
    xe = np.array([[-23.590648, 66.144179, -75.889161], [-29.521359, 61.038840, -79.410620],
                   [-29.043463, 62.883414, -70.480779], [-22.938065, 67.011399, -70.941655],
                   [-25.388475, 69.391507, -74.702269], [-30.443369, 65.430584, -78.291924],
                   [-31.737259, 65.983543, -70.814725], [-25.255244, 70.686230, -70.784244]])
    node = np.array([-23.802414, 69.482746, -79.396306])
    assert S.brick_winding(xe, node) == pytest.approx(0.0, abs=1e-9)
    assert not S.inside_bricks(xe[None], node[None])[0]
    from solver.core.element import shape_functions
    xi = rng.uniform(-0.9, 0.9, (50, 3))
    pts = np.einsum("pa,ai->pi", shape_functions(xi), xe)
    assert S.inside_bricks(np.repeat(xe[None], 50, axis=0), pts).all()
    assert S.brick_winding(xe, xe.mean(axis=0)) == pytest.approx(1.0)
    outside = np.einsum("pa,ai->pi", shape_functions(np.column_stack(
        [np.full(50, 1.2), xi[:, 1:]])), xe)                   # beyond the face xi = 1
    assert not S.inside_bricks(np.repeat(xe[None], 50, axis=0), outside).any()


def test_probe_depth_is_the_distance_to_the_bilinear_face(rng):
    """The probe's depth of a node behind a warped lip face: its distance to the face's
    bilinear surface (minimized over (s, t) by scipy), not to either two-triangle split,
    which differ from it by up to half the warp."""
    from scipy.optimize import minimize
    probe = S.Probe.__new__(S.Probe)
    probe.faces = np.array([[0, 1, 2, 3]])
    probe._w, probe._sub = S.face_sampling(S.FACE_DIVISIONS)
    off = []
    for _ in range(10):
        q = np.array([[-2.0, -2.0, 0.6], [2.0, -2.0, -0.6], [2.0, 2.0, 0.6], [-2.0, 2.0, -0.6]])
        q += rng.normal(0.0, 0.1, q.shape)
        node = np.append(rng.uniform(-1.5, 1.5, 2), rng.uniform(-0.3, 0.3))
        x = np.vstack([q, node])

        def bilinear(z):
            s, t = z
            w = 0.25 * np.array([(1 - s) * (1 - t), (1 + s) * (1 - t), (1 + s) * (1 + t),
                                 (1 - s) * (1 + t)])
            return np.sum((w @ q - node) ** 2)

        best = min(minimize(bilinear, z0, method="Nelder-Mead",
                            options=dict(xatol=1e-10, fatol=1e-14)).fun
                   for z0 in ([0, 0], [0.5, 0.5], [-0.5, 0.5], [0.5, -0.5], [-0.5, -0.5]))
        exact = np.sqrt(best)
        assert probe.face_distance(x, 4) == pytest.approx(exact, abs=2e-3)
        split = min(float(S.point_triangle_distance(node, q[[a]], q[[b]], q[[c]])[0])
                    for a, b, c in ((0, 1, 2), (0, 2, 3)))
        off.append(abs(split - exact))
    assert max(off) > 0.1                           # where the split is off by far more


def test_a_refused_step_that_changes_the_state_is_caught(monkeypatch):
    def broken_step(self, t_end):
        self.face.model.u = self.face.u + 1e-3           # a silently wrong "refusal"
        return StepStats(converged=False, reason="fake")
    monkeypatch.setattr(Simulation, "step", broken_step)
    run = S.run_case(QUICK["tiny_steps"], probe=False)
    assert not run.passed
    assert any("refused step changed the state" in p for p in run.problems)


def test_a_refusal_that_leaves_a_hidden_trace_is_caught(monkeypatch):
    # the refused step leaves u, v, t and the activations as they were, but marks the
    # instance: later outputs move by 1e-9 mm, which only the replay can see
    step, outputs = Simulation.step, Simulation.outputs

    def marking_step(self, t_end):
        stats = step(self, t_end)
        if not stats.converged:
            self.trace = 1e-9
        return stats

    def traced_outputs(self):
        out = outputs(self)
        return {**out, "lip_aperture": out["lip_aperture"] + getattr(self, "trace", 0.0)}
    monkeypatch.setattr(Simulation, "step", marking_step)
    monkeypatch.setattr(Simulation, "outputs", traced_outputs)
    run = S.run_case(QUICK["refusal"], probe=False)
    assert run.refused == [1]
    assert any("differs from a replay without the refused steps" in p for p in run.problems)


def test_halved_scene_halves_the_substep_controls():
    scene = S.halved(QUICK["bang_bang_20hz"].scene)
    from solver.app.scene import Scene, parse_scene
    sc, default = parse_scene(scene), Scene()
    assert sc.substep_tol == default.substep_tol / 4
    assert sc.max_substep == default.max_substep / 2
    assert parse_scene(QUICK["bang_bang_20hz"].scene).hold == "step"


def test_the_realtime_configuration_runs_the_shipped_model_at_halved_substeps():
    """A case at fidelity realtime drives all ten muscles (the shipped model's key), a case
    that scales a force is not applicable there, and its halved scene halves the reduced
    model's substep."""
    from solver.app.scene import parse_scene
    from solver.entry import open_simulation
    from solver.face.anatomy.base import MUSCLE_NAMES
    from solver.rom.stepper import H_MAX
    from solver.rom.store import find_model
    on = S.configured(QUICK["pressed_released"], "generic", None, "realtime")
    assert on.name == "pressed_released@realtime" and on.not_applicable is None
    assert on.scene["muscles"]["driven"] == list(MUSCLE_NAMES)
    find_model(parse_scene(on.scene))                   # shipped: no ModelNotTrained
    assert "force scales" in S.configured(QUICK["refusal"], fidelity="realtime").not_applicable
    assert S.configured(QUICK["refusal"], fidelity="fast").not_applicable is None
    sims = [open_simulation(parse_scene(c.scene)) for c in (on, on.halved())]
    assert [s.stepper.h_max for s in sims] == [H_MAX, H_MAX / 2]


def test_a_realtime_case_counts_its_fallbacks(monkeypatch):
    """A reduced run that hands over to the full model says so (CaseRun.fallbacks, a note
    in the report): here the lips pressed, with a contact limit below what the reduced
    contact reaches."""
    import warnings
    import solver.rom.simulation as rs
    from dataclasses import replace
    on = S.configured(QUICK["pressed_released"], "generic", None, "realtime")
    run = S.run_case(replace(on, steps=on.steps[:2]), probe=False)
    assert run.passed and run.fallbacks == 0, _explain(run)
    monkeypatch.setattr(rs, "TOLERANCE", 1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rs.TrustWarning)
        run = S.run_case(replace(on, steps=on.steps[:2]), probe=False)
    assert run.passed and run.fallbacks == 1, _explain(run)


def test_case_scenes_round_trip_through_toml(tmp_path):
    from solver.app.scene import load_scene, parse_scene
    for case in QUICK.values():
        path = tmp_path / f"{case.name}.toml"
        path.write_text(S.to_toml(case.scene))
        assert load_scene(path) == parse_scene(case.scene), case.name


# ------------------------------------------------------------------ random sequences

@pytest.mark.slow                   # 85 s on a slow day: out of the default suite
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.lists(st.floats(0.0, 1.0), min_size=10, max_size=10), min_size=2,
                max_size=4), st.sampled_from([0.002, 0.01, 0.03]))
def test_random_activation_sequences(sim, probe, sequence, step):
    start = sim.get_state()
    try:
        for acts in sequence:
            d0 = sim.integrator.dissipated
            sim.set_activations(dict(zip(MUSCLE_NAMES, acts)))
            stats = sim.step(sim.t + step)
            assert stats.converged, stats.reason
            assert stats.substeps >= 1 and stats.cutbacks >= 0
            assert sim.outputs()["cutbacks"] == stats.cutbacks
            assert sim.integrator.dissipated >= d0
            measures, problems = S.check_state(sim, probe)
            assert not problems, problems
    finally:
        sim.set_state(start)


# ------------------------------------------------------------------- full versions

# {case name: reason}: full cases known to fail, run as strict expected failures (none:
# `python benchmarks/stress.py` passes every case, docs/stability.md)
KNOWN = {}


def _full_cases():
    """The full cases, those in KNOWN as strict expected failures."""
    return [pytest.param(c, id=c.name, marks=pytest.mark.xfail(strict=True,
                                                                reason=KNOWN[c.name]))
            if c.name in KNOWN else pytest.param(c, id=c.name) for c in S.cases(full=True)]


@pytest.mark.slow
@pytest.mark.parametrize("case", _full_cases())
def test_full_case(case):
    run = S.run_case(case)
    assert run.passed, _explain(run)
    if case.halving:
        half = S.run_case(case.halved(), probe=False)
        assert half.passed, _explain(half)
        assert S.halving_change(run, half) <= S.halving_limit(run)


def test_randomized_campaign_through_the_fmu_a_few_seeds(tmp_path):
    """Three seeds of benchmarks/fmu_campaign.py (the whole campaign is 200 of 0.1 s at
    balanced): random schedules of all ten muscles at random 0.1-20 ms steps, 30 ms each,
    through the FMU's default scene on the coarse generic half face, contact on; every step
    taken, outputs sane, no penetration measured outside the model, clean exit."""
    import sys
    from conftest import ROOT
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from fmu_campaign import run_campaign
    rows, failed, _ = run_campaign([0, 1, 2], 0.03, "", "coarse", 3, 1, tmp_path)
    assert failed == {}
    assert [r[0] for r in rows] == [0, 1, 2]
    assert all(r[1] > 0 and r[5] == "pass" for r in rows), rows
    assert all(max(r[3], r[4]) <= S.CONTACT_TOLERANCE for r in rows), rows
