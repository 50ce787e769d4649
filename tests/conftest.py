"""Shared fixtures: a random generator, the FMU built once per test session, and a tiny
realtime (reduced-order) model trained once per session."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from solver.core.numba_config import configure_numba
from solver.face.anatomy.reference import reference_face as _reference_face
from solver.face.anatomy.reference import reference_face_dir

configure_numba()                          # as the FMU slave and the CLI do

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = Path(__file__).parent / "fmu_scripts"


WARM_FROM = 50      # a session of more tests than this compiles the kernels first


def _warm(config):
    from solver.app.warm import warm_kernels
    capture = config.pluginmanager.getplugin("capturemanager")

    def log(line):
        with capture.global_and_fixture_disabled():
            print(f"conftest: {line}", file=sys.stderr, flush=True)
    warm_kernels(log=log)


def pytest_sessionstart(session):
    """On a cold kernel cache, a session on xdist workers (the suite's default) compiles
    the solver's kernels on all cores first (solver/app/warm.py), in the controller before
    the workers start, instead of each worker compiling them one after another."""
    config = session.config
    if not hasattr(config, "workerinput") and getattr(config.option, "numprocesses", None):
        _warm(config)


def pytest_collection_finish(session):
    """The same for a long session without workers."""
    config = session.config
    if not hasattr(config, "workerinput") and not getattr(config.option, "numprocesses",
                                                          None) \
            and len(session.items) > WARM_FROM:
        _warm(config)


# the published reference face is never in the repository: its tests skip where it is absent
needs_reference_face = pytest.mark.skipif(
    _reference_face() is None, reason=f"reference face data not found in {reference_face_dir()} "
    "(set FACEFMU_REFERENCE_FACE to its folder)")


@pytest.fixture(scope="session")
def reference_face():
    """The reference face's folder (solver.face.anatomy.reference); skips where absent."""
    folder = _reference_face()
    if folder is None:
        pytest.skip(f"reference face data not found in {reference_face_dir()}")
    return folder


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def fmu(tmp_path_factory):
    """The FMU built from this checkout by build_fmu.py (once per session), with the
    corrected pythonfmu wrapper (docs/dev-notes/exit-crash.md): without it the build fails
    here rather than the FMU tests' processes aborting at exit."""
    dest = tmp_path_factory.mktemp("fmu")
    run = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", str(dest),
                          "--require-patched-wrapper"],
                         capture_output=True, text=True, cwd=tmp_path_factory.getbasetemp())
    assert run.returncode == 0, run.stderr
    path = dest / "FaceFMU.fmu"
    assert path.is_file()
    return path


ROM_DRIVEN = ("RIS", "DLI", "OOP")


def _train_tiny(folder, runs, jaw_runs, contact=True):
    from solver.app.fidelity import apply_fidelity
    from solver.app.scene import Scene
    from solver.app.simulation import Simulation
    from solver.rom.store import load_model, model_path
    from solver.rom.train import collect, snapshot_tasks, train
    scene = apply_fidelity(Scene(name="rom_test", driven=ROM_DRIVEN, lip_contact=contact,
                                 teeth_contact=contact, fidelity="realtime"), "realtime")
    scene = scene.with_overrides(level="coarse", rows=None)
    full = Simulation(scene)
    path = train(scene, sim=full, runs=runs, duration=0.05, interval=0.005, seed=3,
                 calibration_runs=1, out=folder / "model.npz", progress=False, sim_only=True,
                 jaw_runs=jaw_runs)
    shutil.copy(path, model_path(full.scene, folder))
    arrays, meta = load_model(path)
    tasks = snapshot_tasks(full.scene, runs, 0.05, 0.005, 3, jaw_runs=jaw_runs)  # the same
    results = collect(full.scene, tasks, sim=full, progress=False)
    return {"scene": full.scene, "full": full, "path": path, "arrays": arrays, "meta": meta,
            "tasks": tasks, "results": results, "folder": folder}


@pytest.fixture(scope="session")
def trained(tmp_path_factory):
    """A realtime model trained in this process on a tiny set: the coarse generic half face
    (the scene's fidelity "realtime", its level "coarse") with OOP, RIS and DLI driven,
    teeth and lip contact, 3 full-order runs of 0.05 s with the jaw closed (5 ms
    snapshots; none read from or kept in the user's snapshot cache). The model is saved
    as model.npz and under its key's name in `folder` (for FACEFMU_ROM_DIR look-ups)."""
    return _train_tiny(tmp_path_factory.mktemp("rom"), 3, 0)


@pytest.fixture(scope="session")
def trained_smooth(tmp_path_factory):
    """As `trained`, without lip and teeth contact (2 runs): a smooth reduced model, for
    the integrators' order of convergence."""
    return _train_tiny(tmp_path_factory.mktemp("rom_smooth"), 2, 0, contact=False)


@pytest.fixture(scope="session")
def trained_jaw(tmp_path_factory):
    """As `trained`, with the jaw: one muscle pattern (which may move the jaw) and one
    run that opens it (solver.rom.train.snapshot_tasks, jaw_runs=1)."""
    return _train_tiny(tmp_path_factory.mktemp("rom_jaw"), 1, 1)


# Tolerances for the comparisons of NewtonOptions on the lip gesture: substep error 1e-2 mm,
# Newton 1e-6 on the residual and 1e-4 mm on its last update, the stiff lip penalty (PENALTY)
REFERENCE_BALANCED = dict(substep_tol=1e-2, newton_rtol=1e-6, newton_utol=1e-4,
                          lip_penalty=1.0)


def gesture_both_ways(option, duration, count):
    """The lip gesture (solver.app.gestures) on the coarse half face (lip and teeth
    contact) for duration s, with NewtonOptions.option off and on: {on: (count(sim) after
    the run, the recorded rows)}. At REFERENCE_BALANCED (substeps 1e-2 mm, Newton 1e-6 and
    1e-4 mm), tighter than `balanced`: the runs must agree to a small multiple of Newton's
    last update."""
    from solver.app.gestures import gesture
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    runs = {}
    for on in (False, True):
        sim = Simulation(parse_scene(gesture(duration)), level="coarse", half=True,
                         **REFERENCE_BALANCED)
        setattr(sim.face.model.newton_options, option, on)
        rows = []
        sim.run(on_record=lambda s, row: rows.append(row))
        runs[on] = (count(sim), rows)
        sim.release()
    return runs


def assert_same_lips(rows0, rows1, tol=1e-4):
    """Two runs' recorded lip protrusion and aperture agree to tol (mm) at every record."""
    assert len(rows0) == len(rows1)
    for a, b in zip(rows0, rows1):
        assert abs(a["lip_protrusion"] - b["lip_protrusion"]) < tol
        assert abs(a["lip_aperture"] - b["lip_aperture"]) < tol


def smooth_rows(sim, h, peaks, read, span=0.04):
    """Drive sim (a Simulation or ReducedSimulation) along a smooth gesture, each muscle of
    peaks {muscle: peak activation} along peak (1 - cos(pi t / span)) / 2 at caller steps
    of h (each sees its activations at its end); (k, m) the outputs read(sim) (a list of
    m numbers) every 5 ms."""
    n, every = int(round(span / h)), int(round(0.005 / h))
    rows = []
    for k in range(1, n + 1):
        s = 0.5 * (1.0 - np.cos(np.pi * k * h / span))
        sim.set_activations({m: peak * s for m, peak in peaks.items()})
        assert sim.step(k * h).converged
        if k % every == 0:
            rows.append(read(sim))
    return np.array(rows)
