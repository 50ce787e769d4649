"""The motor-control example: its inverse model, and the two-FMU co-simulation through
fmpy (examples/cosim_speech.py run as a user runs it, in a fresh process)."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT

CONTROL = ROOT / "examples" / "motor_control"
sys.path.insert(0, str(CONTROL))
from lipmc_inverse import NAMES, OUTPUTS, LipMap, activations  # noqa: E402


@pytest.fixture(scope="module")
def lip_map():
    return LipMap.load(CONTROL / "inverse_model.json")


def test_the_map_jacobian_matches_finite_differences(lip_map, rng):
    m, _ = lip_map
    for w, jaw in zip(rng.random((5, 4)), rng.uniform(0.0, 10.0, 5)):
        J = m.jacobian(w, jaw)
        h = 1e-6
        fd = np.stack([(m(w + h * e, jaw) - m(w - h * e, jaw)) / (2 * h) for e in np.eye(4)],
                      axis=1)
        assert np.allclose(J, fd, atol=1e-6, rtol=1e-5)


def test_the_inverse_reaches_what_the_map_can_do_within_bounds(lip_map, rng):
    m, _ = lip_map
    q = np.ones(3)
    for w, jaw in zip(rng.random((10, 4)), rng.uniform(0.0, 10.0, 10)):
        y = m(w, jaw)
        got = m.inverse(y, q, lam=1e-3, jaw=jaw)
        assert np.all((got >= 0) & (got <= 1))
        assert np.abs(m(got, jaw) - y).max() < 0.05
    far = m.inverse([30.0, 10.0, 80.0], q)           # out of reach: held at the bounds
    assert np.all((far >= 0) & (far <= 1))


def test_the_identified_map_and_targets_are_the_faces(lip_map):
    """The stored fit is good, every stored target is the map at its intent and jaw
    opening, and the open vowel /a/ opens the lips by at least 8 mm with the jaw."""
    m, data = lip_map
    assert max(data["fit"]["loo_rms"]) < 0.3
    assert data["provenance"]["face"]["scene"] == "default"
    assert len(data["targets"]) >= 5
    for tg in data["targets"]:
        assert 0.1 <= tg["duration"] <= 0.25
        y = m(np.array([tg["intent"][n] for n in NAMES]), tg["jaw_opening"])
        for o, v in zip(OUTPUTS, y):
            assert tg[o] == pytest.approx(max(v, 0.0) if o == "lip_aperture" else v, abs=0.06)
    a_target = next(tg for tg in data["targets"] if tg["phoneme"] == "a")
    assert a_target["jaw_opening"] > 0 and a_target["lip_aperture"] >= 8.0
    a = activations([1.0, 0.0, 0.5, 0.0])
    assert a["LLSAN"] == a["DLI"] == 1.0 and a["RIS"] == a["ZYG"] == 0.5 and a["OOP"] == 0.0


def test_the_stored_responses_are_todays_face(tmp_path):
    """The first three stored samples (rest, open, round), run again through today's
    FaceFMU, end within 0.05 mm of the stored responses: the shipped map is not stale."""
    run = subprocess.run([sys.executable, str(CONTROL / "identify.py"), "--check", "3"],
                         capture_output=True, text=True, timeout=900, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "3 stored samples against today's FaceFMU" in run.stdout


def _example(tmp_path, targets):
    path = tmp_path / "targets.json"
    path.write_text(json.dumps(targets))
    run = subprocess.run([sys.executable, str(ROOT / "examples" / "cosim_speech.py"),
                          "--targets", str(path), "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=900, cwd=tmp_path)
    return run


@pytest.fixture(scope="module")
def two_targets(tmp_path_factory):
    """examples/cosim_speech.py on /a/ in a window of 0.1 s, then /u/ in its own of 0.2 s
    (the main job's: the lips close from /a/'s 13 mm and protrude), from the identified
    targets: (the finished process, its targets, its output folder)."""
    tmp_path = tmp_path_factory.mktemp("two_targets")
    data = json.loads((CONTROL / "inverse_model.json").read_text())
    targets = [dict(tg, duration=0.1) if tg["phoneme"] == "a" else tg
               for tg in data["targets"] if tg["phoneme"] in ("a", "u")]
    return _example(tmp_path, targets), targets, tmp_path / "out"


def test_the_cosimulation_reaches_two_targets(two_targets):
    """Both targets met at the end of their windows (aperture, protrusion within 0.3 mm,
    width within 0.5 mm), exit status 0; checked here again on the CSV the example wrote."""
    run, targets, out = two_targets
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "all 2 targets met" in run.stdout
    rows = list(csv.DictReader(open(out / "cosim.csv")))
    end = 0.0
    for tg in targets:
        end += tg["duration"]
        row = min(rows, key=lambda r: abs(float(r["time"]) - end))
        for o in tg["targeted"]:
            tol = 0.5 if o == "lip_width" else 0.3
            assert abs(float(row[o]) - tg[o]) <= tol, (tg["phoneme"], o, row[o], tg[o])
    assert (out / "cosim.png").stat().st_size > 10_000


def test_the_example_exits_nonzero_when_a_target_is_out_of_reach(tmp_path):
    targets = [{"phoneme": "x", "duration": 0.05, "targeted": ["lip_aperture"],
                "lip_aperture": 30.0, "lip_protrusion": 0.0, "lip_width": 50.0}]
    run = _example(tmp_path, targets)
    assert run.returncode == 1, run.stdout[-3000:] + run.stderr[-3000:]
    assert "MISSED" in run.stdout and "FAILED: 1 of 1 targets missed" in run.stdout


def test_libcosim_runs_the_same_system_and_agrees_with_fmpy(two_targets, tmp_path):
    """The OSP system structure in libcosim (a second master) against fmpy: /a/ in 0.1 s
    met, the lip outputs within 0.01 mm of fmpy's at every step. The fmpy run is the first
    0.1 s of the two-target run: the controller is causal (a window's steps use that
    window's target only), so its /a/ window is the /a/-only run. --out is relative, as a
    user types it."""
    pytest.importorskip("libcosimpy")
    run, targets, out = two_targets
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    first = targets[:1]
    assert first[0]["phoneme"] == "a" and first[0]["duration"] == 0.1
    path = tmp_path / "targets.json"
    path.write_text(json.dumps(first))
    with open(out / "cosim.csv") as f:
        lines = f.readlines()
    fmpy = tmp_path / "fmpy.csv"
    fmpy.write_text("".join(lines[:21]))                    # the header and 20 steps of 5 ms
    run = subprocess.run([sys.executable, str(ROOT / "examples" / "cosim_libcosim.py"),
                          "--targets", str(path), "--out", "out", "--compare", str(fmpy)],
                         capture_output=True, text=True, timeout=900, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "the masters agree" in run.stdout
    ours = list(csv.DictReader(open(tmp_path / "out" / "cosim.csv")))
    theirs = list(csv.DictReader(open(fmpy)))
    assert len(ours) == len(theirs) == 20
    assert abs(float(ours[-1]["time"]) - 0.1) < 1e-9
    assert max(abs(float(a[o]) - float(b[o])) for a, b in zip(ours, theirs)
               for o in OUTPUTS) <= 0.01
    assert max(float(r["lip_aperture"]) for r in ours) > 3.0     # /a/ opened the lips


@pytest.mark.slow
def test_the_main_job_meets_every_target(tmp_path):
    """The README's main job, whole: every identified target met, exit status 0."""
    run = subprocess.run([sys.executable, str(ROOT / "examples" / "cosim_speech.py"),
                          "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=1800, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    n = len(json.loads((CONTROL / "inverse_model.json").read_text())["targets"])
    assert f"all {n} targets met" in run.stdout and "MISSED" not in run.stdout


def test_a_plain_libcosim_script_exits_without_an_fmu_error(two_targets, tmp_path):
    """libcosim terminates the FMUs from its own teardown while Python shuts down (imports
    fail then): a script that builds the speech system's execution, steps it and ends
    normally exits 0 with no FMU error on its output."""
    pytest.importorskip("libcosimpy")
    run, _, out = two_targets
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    for name in ("FaceFMU.fmu", "LipMotorControl.fmu"):
        (tmp_path / name).write_bytes((out / name).read_bytes())
    (tmp_path / "OspSystemStructure.xml").write_text(
        (CONTROL / "OspSystemStructure.xml").read_text())
    (tmp_path / "plain.py").write_text(
        "from libcosimpy.CosimExecution import CosimExecution\n"
        "execution = CosimExecution.from_osp_config_file('OspSystemStructure.xml')\n"
        "assert execution.simulate_until(int(0.02e9))\n"
        "print('simulated')\n")
    run = subprocess.run([sys.executable, "plain.py"], capture_output=True, text=True,
                         timeout=600, cwd=tmp_path)
    text = run.stdout + run.stderr
    assert run.returncode == 0 and "simulated" in run.stdout, text[-3000:]
    assert "[error]" not in text and "Fatal" not in text, text[-3000:]
