"""The co-simulation master (facefmu.cosim) and batches on dask (facefmu.batch), on the
coarse generic face: a batch reproduces each utterance run alone, contains its failures,
survives a dead worker; a controller with other variable names runs from its system
description."""

import csv
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from conftest import ROOT

pytest.importorskip("dask.distributed")
pytest.importorskip("fmpy")

from facefmu import speech  # noqa: E402
from facefmu.batch import (THREAD_ENV, Batch, Utterance, from_targets, grid,  # noqa: E402
                           serial)
from facefmu.cosim import Master, Record, read_system  # noqa: E402

CONTROL = ROOT / "examples" / "motor_control"
COARSE = {"fidelity": "", "level": "coarse"}        # the default scene's own, coarse mesh


def _pythonfmu(script, dest):
    """Build a pythonfmu FMU from script into dest, with the corrected wrapper."""
    run = subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(script),
                          "-d", str(dest), "--no-external-tool",
                          *map(str, script_files(script))],
                         capture_output=True, text=True, cwd=script.parent)
    assert run.returncode == 0, run.stdout + run.stderr
    fmu = dest / f"{_class_name(script)}.fmu"
    run = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--fix-wrapper",
                          str(fmu), "--require-patched-wrapper"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
    return fmu


def script_files(script):
    if script.name == "lip_motor_control.py":
        return [CONTROL / "lipmc_inverse.py", CONTROL / "inverse_model.json"]
    return []


def _class_name(script):
    return {"lip_motor_control.py": "LipMotorControl", "gap_control.py": "GapControl"}[
        script.name]


@pytest.fixture(scope="module")
def speech_system(fmu, tmp_path_factory):
    """The speech system of examples/motor_control/OspSystemStructure.xml on the coarse
    face, with this checkout's FMUs."""
    control = _pythonfmu(CONTROL / "lip_motor_control.py", tmp_path_factory.mktemp("ctrl"))
    system = read_system(CONTROL / "OspSystemStructure.xml",
                         fmus={"face": fmu, "control": control})
    system.initial["face"].update(COARSE)
    return system


@pytest.fixture(scope="module")
def utterances(tmp_path_factory):
    """Four utterances of two 30 ms windows each, from the identified targets."""
    folder = tmp_path_factory.mktemp("targets")
    base = json.loads((CONTROL / "inverse_model.json").read_text())["targets"]
    paths = []
    for k in range(4):
        p = folder / f"u{k}.json"
        p.write_text(json.dumps([dict(base[k], duration=0.03),
                                 dict(base[(k + 1) % len(base)], duration=0.03)]))
        paths.append(p)
    return from_targets(paths)


@pytest.fixture(scope="module")
def alone(speech_system, utterances):
    """Each utterance alone in a process of its own."""
    return serial(speech_system, utterances, speech.records(speech_system))


def test_each_utterance_alone_runs_and_is_scored(alone, utterances):
    for u, s in zip(utterances, alone.summary):
        rows = alone.trajectories[u.name]
        assert s["ok"], s["reason"]
        assert s["steps"] == len(rows) == 12
        assert s["targets"] == 2 and 0 <= s["met"] <= 2
        assert math.isclose(rows[-1]["time"], 0.06)
        for col in ("phoneme", "target_aperture", "lip_aperture", "OOP", "jaw_opening",
                    "incisor_opening"):
            assert col in rows[0]
    # the controller acted: some muscle is on by the end of every utterance
    assert all(max(r[m] for m in ("OOP", "DLI", "RIS", "LLSAN", "MENT")) > 0.01
               for r in (alone.trajectories[u.name][-1] for u in utterances))


def test_a_batch_on_two_workers_equals_each_utterance_alone(speech_system, utterances,
                                                           alone, tmp_path):
    """Identical trajectories (every recorded value, every step) and the same scores; the
    two workers both took tasks; the tables are written."""
    with Batch(speech_system, speech.records(speech_system), n_workers=2) as batch:
        result = batch.run(utterances, progress=False)
    for u, s, ref in zip(utterances, result.summary, alone.summary):
        assert s["ok"], s["reason"]
        assert result.trajectories[u.name] == alone.trajectories[u.name]
        assert (s["met"], s["max_error_aperture"]) == (ref["met"], ref["max_error_aperture"])
    assert len({s["worker"] for s in result.summary}) == 2
    traj, summ = result.write(tmp_path / "out")
    assert traj.stat().st_size > 1000 and summ.stat().st_size > 100
    head = traj.read_text().splitlines()[0] if traj.suffix == ".csv" else ""
    assert traj.suffix == ".parquet" or head.startswith("utterance,time,phoneme")


def test_failed_utterances_are_recorded_and_the_rest_complete(speech_system, utterances,
                                                             alone, tmp_path):
    """An out-of-reach target (30 mm aperture), a NaN target, an unknown fidelity and a
    NaN open-loop input: each recorded with its reason; the others as when run alone."""
    far = tmp_path / "far.json"
    far.write_text(json.dumps([{"phoneme": "x", "duration": 0.03,
                                "targeted": ["lip_aperture"], "lip_aperture": 30.0,
                                "lip_protrusion": 0.0, "lip_width": 50.0}]))
    nan = tmp_path / "nan.json"
    nan.write_text('[{"phoneme": "y", "duration": 0.03, "targeted": ["lip_aperture"], '
                   '"lip_aperture": NaN, "lip_protrusion": 0.0, "lip_width": 50.0}]')
    good = utterances[:2]
    bogus = Utterance("bogus", 0.01, {"face": {"fidelity": "bogus"}})
    nan_input = Utterance("nan_input", 0.02, inputs={"face.OOM": [0.0, math.nan, 0.0, 0.0]})
    batch_in = from_targets([far]) + [good[0]] + from_targets([nan]) + [bogus, nan_input,
                                                                         good[1]]
    with Batch(speech_system, speech.records(speech_system), n_workers=2) as batch:
        result = batch.run(batch_in, progress=False)
    by = dict(zip([u.name for u in batch_in], result.summary))
    assert by["far"]["ok"] and by["far"]["met"] == 0
    assert "targets missed: /x/ lip_aperture" in by["far"]["reason"]
    assert not by["nan"]["ok"] and "lip_aperture = nan" in by["nan"]["reason"]
    assert not by["bogus"]["ok"] and "'bogus'" in by["bogus"]["reason"]
    assert not by["nan_input"]["ok"]
    assert "OOM = nan" in by["nan_input"]["reason"], by["nan_input"]["reason"]
    for u in good:
        assert by[u.name]["ok"]
        assert result.trajectories[u.name] == alone.trajectories[u.name]


def test_a_killed_worker_has_its_task_rerun(speech_system, utterances, alone):
    """SIGKILL to a worker while it runs an utterance: dask reruns the task on another
    worker (the nanny restarts the dead one) and the batch completes, unchanged."""
    with Batch(speech_system, speech.records(speech_system), n_workers=2) as batch:
        batch.warmup()
        pids = batch.client.run(os.getpid)
        killed = []

        def kill():
            deadline = time.time() + 120
            while time.time() < deadline and not killed:
                busy = [w for w, tasks in batch.client.processing().items() if tasks]
                if busy:
                    time.sleep(1.0)             # inside the utterance, not at its start
                    os.kill(pids[busy[0]], signal.SIGKILL)
                    killed.append(busy[0])
                time.sleep(0.1)

        thread = threading.Thread(target=kill, daemon=True)
        thread.start()
        result = batch.run(utterances, progress=False)
        thread.join()
    assert killed
    for u, s in zip(utterances, result.summary):
        assert s["ok"], s["reason"]
        assert result.trajectories[u.name] == alone.trajectories[u.name]


def test_a_controller_with_other_variable_names_runs_from_its_description(fmu, tmp_path):
    """tests/fmus/gap_control.py connected through tests/fmus/gap_system.xml: the face
    receives exactly the controller's commands under its own names, and the lips open
    when it asks them to."""
    control = _pythonfmu(ROOT / "tests" / "fmus" / "gap_control.py", tmp_path)
    system = read_system(ROOT / "tests" / "fmus" / "gap_system.xml",
                         fmus={"face": fmu, "gap": control})
    records = speech.records(system) + [Record("cmd", "gap", "depressor", "start")]
    with Master(system, records) as master:
        result = master.run(0.05)
        again = master.run(0.05, {"gap": {"gap_target": 0.0}})
    assert result.ok and again.ok, result.reason + again.reason
    rows = result.rows
    assert [r["DLI"] for r in rows] == [r["cmd"] for r in rows]
    assert rows[0]["DLI"] == 0.0                     # its output before its first step
    assert rows[1]["DLI"] == 1.0                     # gain 0.5 times a 4 mm gap, clipped
    assert rows[1]["jaw_opening"] == 2.0
    assert max(r["lip_aperture"] for r in rows) > rows[0]["lip_aperture"] + 2.0  # opened
    assert max(r["DLI"] for r in again.rows) == 0.0      # the new parameter was applied


def test_the_system_description_is_checked(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<Nope/>")
    with pytest.raises(ValueError, match="OspSystemStructure"):
        read_system(bad)
    with pytest.raises(ValueError, match=r"is not \[column=\]simulator.variable"):
        Record.parse("lip_aperture")
    system = read_system(CONTROL / "OspSystemStructure.xml")
    with pytest.raises(ValueError, match="no such simulator"):
        Master(system).run(0.01, {"nobody": {}})


def test_grid_makes_one_utterance_per_point():
    base = Utterance("u", 0.1, {"control": {"targets_file": "a.json"}})
    points = grid(base, {"control.tau_fb": [0.02, 0.03], "face.fidelity": ["fast", ""]})
    assert len(points) == 4 and len({p.name for p in points}) == 4
    assert points[0].parameters == {"control": {"targets_file": "a.json", "tau_fb": 0.02},
                                    "face": {"fidelity": "fast"}}
    assert base.parameters == {"control": {"targets_file": "a.json"}}


def test_the_cli_runs_one_utterance_and_says_what_it_met(speech_system, utterances,
                                                         alone, tmp_path):
    """`facefmu cosim` on one target file, in its own process: the tracking table, one
    summary line, the two tables written, the exit status 1 where targets were missed,
    trajectories as when run alone."""
    u = utterances[0]
    face, control = speech_system.simulators["face"], speech_system.simulators["control"]
    run = subprocess.run(
        [sys.executable, "-m", "facefmu.cli", "cosim",
         str(CONTROL / "OspSystemStructure.xml"), "--fmu", f"face={face}",
         "--fmu", f"control={control}", "--set", "face.fidelity=", "--set",
         "face.level=coarse", "--targets", u.parameters["control"]["targets_file"],
         "--out", str(tmp_path / "out"), "--format", "csv"],
        capture_output=True, text=True, timeout=600, cwd=tmp_path,
        env={**os.environ, **THREAD_ENV})          # one thread, as the reference ran
    ref = alone.summary[0]
    assert run.returncode == (0 if ref["met"] == ref["targets"] else 1), run.stderr[-2000:]
    assert "lip_aperture" in run.stdout and f"{ref['met']}/2 targets met" in run.stdout
    rows = list(csv.DictReader(open(tmp_path / "out" / "trajectories.csv")))
    assert len(rows) == 12
    assert [float(r["lip_aperture"]) for r in rows] == \
        [r["lip_aperture"] for r in alone.trajectories[u.name]]
    bad = subprocess.run([sys.executable, "-m", "facefmu.cli", "cosim", "nothing.xml",
                          "--stop", "0.01"], capture_output=True, text=True, cwd=tmp_path)
    assert bad.returncode == 2 and "nothing.xml" in bad.stderr
