"""benchmarks/replay.py: a co-simulation CSV's inputs replayed open loop at named settings."""

import csv
import sys

import numpy as np

from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import replay  # noqa: E402


def test_settings_parse_to_scene_fields_with_numbers_and_booleans():
    assert replay.parse_config("main=fidelity:") == ("main", {"fidelity": ""})
    assert replay.parse_config("b=fidelity:fast,substep_tol:0.2,max_substep:5e-3,"
                               "integrator:bdf2,lip_contact:false") == (
        "b", {"fidelity": "fast", "substep_tol": 0.2, "max_substep": 0.005,
              "integrator": "bdf2", "lip_contact": False})


def test_replay_applies_each_rows_inputs_over_its_step(tmp_path):
    """Two 5 ms rows of a cosim CSV replayed on the default scene give what stepping the
    same inputs by hand gives, and the costs of those steps."""
    from solver.app.simulation import Simulation
    rows = [{"time": 0.005 * (k + 1), **{m: 0.0 for m in replay.MUSCLES},
             "jaw_opening": 1.0 * k, "lip_aperture": 0.0, "lip_protrusion": 0.0}
            for k in range(2)]
    rows[1]["OOP"] = 0.6
    path = tmp_path / "cosim.csv"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    times, acts, jaw, outs = replay.read_inputs(path)
    assert times.tolist() == [0.005, 0.01] and acts[1]["OOP"] == 0.6 and jaw[1] == 1.0
    got, cost = replay.replay("default", {"fidelity": ""}, times, acts, jaw)
    sim = Simulation("default")
    want = []
    for t, a, j in zip(times, acts, jaw):
        sim.set_activations(a)
        sim.set_jaw(j, None)
        assert sim.step(t).converged
        want.append([sim.outputs()[o] for o in replay.OUTPUTS])
    assert np.array_equal(got, np.array(want))
    assert cost["substeps"] >= 2 and cost["iterations"] > 0 and cost["dof"] == sim.u.size


def test_before_runs_a_commits_own_code(tmp_path):
    """benchmarks/revision.py: a script run on a commit's worktree imports the solver from
    there (not from this checkout), the worktree goes away after, and an unknown commit
    is refused by name."""
    import subprocess

    import pytest
    import revision
    script = tmp_path / "where.py"
    script.write_text("import json, sys, solver\n"
                      "json.dump({'file': solver.__file__}, open(sys.argv[-1], 'w'))\n")
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                          capture_output=True, text=True).stdout.strip()
    if not head:
        pytest.skip("not a git checkout")
    with revision.checkout("HEAD") as code:
        there = revision.run_json(script, [], code)["file"]
        assert there.startswith(str(code)), there
    assert not code.exists()
    here = revision.run_json(script, [])["file"]
    assert here.startswith(str(ROOT)), here
    with pytest.raises(ValueError, match="no-such-commit"):
        revision.describe("no-such-commit")
