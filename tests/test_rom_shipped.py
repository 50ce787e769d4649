"""The reduced model that ships with the project (solver/rom/models, solver.rom.store):
it matches the current physics, the check that says so can fail, and a fresh build of the
FMU runs `fidelity = "realtime"` with it and no training."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from conftest import ROOT


def test_a_model_ships_for_the_default_scene_and_matches_the_current_physics():
    from solver.app.fidelity import apply_fidelity
    from solver.app.simulation import resolve_scene
    from solver.rom.store import SHIPPED, load_model, model_key, model_path, stale_models
    assert stale_models() == []
    for name in ("default", "speech"):                  # one key, one file
        path = model_path(apply_fidelity(resolve_scene(name), "realtime"), SHIPPED)
        assert path.is_file(), path
    arrays, meta = load_model(path, model_key(apply_fidelity(resolve_scene("default"),
                                                             "realtime")))
    # its provenance: the command that made it and the commit it was made at
    assert meta["command"].startswith("python benchmarks/rom_train.py --ship")
    assert meta["revision"] and "uncommitted" not in meta["revision"]
    # all ten muscles, lip and teeth contact, the jaw over its whole opening range
    assert len(meta["key"]["driven"]) == 10
    assert meta["key"]["lip_contact"] and meta["key"]["teeth_contact"]
    assert meta["jaw_envelope"]["jaw_opening"][1] >= 15.0
    assert path.stat().st_size < 8e6                    # a few MB


def test_the_stale_check_fails_when_a_physics_constant_of_the_key_changes(monkeypatch):
    import solver.face.muscles as muscles
    import solver.rom.store as store
    monkeypatch.setattr(store, "PHYSICS", store.PHYSICS + 1)
    stale = store.stale_models()
    assert stale and all("physics" in why for _, why in stale)
    monkeypatch.undo()
    monkeypatch.setattr(muscles, "SIGMA_MAX_MPA", 1.01 * muscles.SIGMA_MAX_MPA)
    stale = store.stale_models()
    assert stale and all("muscles" in why for _, why in stale)


def test_the_stale_check_fails_when_the_generic_face_changes_shape(monkeypatch):
    import solver.face.anatomy.generic_shape as shape
    import solver.rom.store as store
    monkeypatch.setattr(shape, "SLIT_OPEN", 0.5 * shape.SLIT_OPEN)
    store.generic_geometry.cache_clear()
    try:
        stale = store.stale_models()
    finally:
        monkeypatch.undo()
        store.generic_geometry.cache_clear()
    assert stale and all("geometry" in why for _, why in stale)


def test_the_stale_check_reports_a_broken_file(tmp_path):
    from solver.rom.store import stale_models
    (tmp_path / "rom-generic-x.npz").write_bytes(b"not a model")
    [(name, why)] = stale_models(tmp_path)
    assert name == "rom-generic-x.npz" and why


FMPY = textwrap.dedent("""
    import json, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    path, out = sys.argv[1], sys.argv[2]
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), instanceName="rt",
                    modelIdentifier=md.coSimulation.modelIdentifier)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setString([vr["fidelity"]], ["realtime"])
    fmu.exitInitializationMode()
    t, dt, rows = 0.0, 1e-3, []
    while t < 0.3 - 1e-9:
        a = min(t / 0.15, 1.0)
        fmu.setReal([vr["OOP"], vr["RIS"]], [a, 0.5 * a])
        fmu.doStep(t, dt)
        t += dt
        rows.append(fmu.getReal([vr["lip_aperture"], vr["lip_protrusion"]])
                    + fmu.getInteger([vr["rom_fallbacks"]]))
    fmu.terminate()
    fmu.freeInstance()
    json.dump(rows, open(out, "w"))
""")


def test_a_fresh_fmu_runs_fidelity_realtime_without_training(tmp_path):
    """python build_fmu.py, then fidelity "realtime" through fmpy for 0.3 s of OOP + RIS
    at 1 ms steps, with an empty folder of reduced models (FACEFMU_ROM_DIR, where a
    trained or cached model would be; numba's compiled kernels are not models and stay
    shared): the shipped model, no training, no fallback."""
    build = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest",
                            str(tmp_path)], capture_output=True, text=True, cwd=tmp_path)
    assert build.returncode == 0, build.stderr
    script, out = tmp_path / "rt.py", tmp_path / "out.json"
    script.write_text(FMPY)
    env = dict(os.environ, FACEFMU_ROM_DIR=str(tmp_path / "cache" / "rom"))
    run = subprocess.run([sys.executable, str(script), str(tmp_path / "FaceFMU.fmu"),
                          str(out)], capture_output=True, text=True, cwd=tmp_path,
                         timeout=900, env=env)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    rows = np.array(json.loads(out.read_text()))
    assert len(rows) == 300 and np.all(np.isfinite(rows))
    assert rows[-1, 1] > 0.5                            # OOP protrudes the lips
    assert np.all(rows[:, 2] == 0)                      # the reduced model all along
    assert not (tmp_path / "cache" / "rom").exists() or \
        not any((tmp_path / "cache" / "rom").glob("*.npz"))     # nothing trained
