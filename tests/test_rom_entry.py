"""The realtime fidelity through its three entry points: a scene file's `fidelity`, the
command line's `--fidelity realtime` and the FMU's `fidelity` parameter, with the
session's tiny trained model (conftest.py `trained`) and without a model (a clear error
naming the training command)."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

from conftest import ROM_DRIVEN, ROOT

SCENE = textwrap.dedent(f"""
    [scene]
    name = "rom_entry"
    fidelity = "realtime"
    duration = 0.01

    [anatomy]
    level = "coarse"                # the tiny model's mesh (the file's keys win)
    rows = 1

    [muscles]
    driven = {list(ROM_DRIVEN)}

    [effects]
    lip_contact = true
    teeth_contact = true

    [outputs]
    interval = 0.002

    [[schedule]]
    muscle = "OOP"
    kind = "ramp"
    start = 0.0
    end = 0.01
    to = 0.6
""").replace("'", '"')


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "rom_entry.toml"
    path.write_text(SCENE)
    return path


def test_scene_file_fidelity_realtime_builds_the_reduced_model(trained, scene_file,
                                                               monkeypatch):
    from solver.rom.simulation import ReducedSimulation
    from solver.rom.store import model_key
    from solver.app.scene import load_scene
    from solver.entry import open_simulation
    scene = load_scene(scene_file)
    assert scene.fidelity == "realtime" and scene.level == "coarse"
    assert model_key(scene) == model_key(trained["scene"])
    monkeypatch.setenv("FACEFMU_ROM_DIR", str(trained["folder"]))
    sim = open_simulation(scene_file, loaded_anatomy=trained["full"].anatomy)
    assert isinstance(sim, ReducedSimulation) and sim.mode == "rom"
    rows = sim.run()
    assert rows[-1]["time"] == pytest.approx(0.01) and rows[-1]["lip_protrusion"] != 0.0


def test_simulation_is_the_full_model_and_refuses_a_reduced_fidelity(scene_file):
    """Simulation builds the full model: a scene file that names "realtime" gets it at the
    realtime knobs; fidelity="realtime" given to it is refused, naming open_simulation."""
    from solver.core.errors import ParameterError
    from solver.app.simulation import Simulation
    sim = Simulation(scene_file)
    assert type(sim) is Simulation and sim.scene.fidelity == "realtime"
    assert (sim.scene.level, sim.scene.half) == ("coarse", True)
    with pytest.raises(ParameterError, match=r"open_simulation\(scene, fidelity='realtime'\)"):
        Simulation("default", fidelity="realtime")


def test_scene_file_realtime_without_a_model_names_the_training_command(scene_file,
                                                                        tmp_path,
                                                                        monkeypatch):
    from solver.rom import ModelNotTrained
    from solver.entry import open_simulation
    monkeypatch.setenv("FACEFMU_ROM_DIR", str(tmp_path / "empty"))
    with pytest.raises(ModelNotTrained, match=r"rom_train\.py --scene SCENE.*TOML"):
        open_simulation(scene_file)


def test_cli_run_fidelity_realtime(trained, scene_file, tmp_path, monkeypatch, capsys):
    from facefmu import cli
    plain = tmp_path / "plain.toml"                 # the scene without its fidelity key
    plain.write_text(SCENE.replace('fidelity = "realtime"\n', ""))
    monkeypatch.setenv("FACEFMU_ROM_DIR", str(tmp_path / "empty"))
    # --level: the tiny model's mesh (over the preset's)
    assert cli.main(["run", str(plain), "--fidelity", "realtime", "--level", "coarse",
                     "--out", str(tmp_path), "--quiet"]) == 2
    assert "rom_train.py" in capsys.readouterr().err
    monkeypatch.setenv("FACEFMU_ROM_DIR", str(trained["folder"]))
    assert cli.main(["run", str(plain), "--fidelity", "realtime", "--level", "coarse",
                     "--out", str(tmp_path), "--quiet"]) == 0
    csv = (tmp_path / "rom_entry.csv").read_text().splitlines()
    assert len(csv) == 1 + 6                        # header, t = 0 ... 0.01 s by 2 ms


FMPY = textwrap.dedent("""
    import json, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave
    path, out, scene = sys.argv[1], sys.argv[2], sys.argv[3]
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzip, res = extract(path), {}
    def make(name, scene):
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip, instanceName=name,
                        modelIdentifier=md.coSimulation.modelIdentifier)
        fmu.instantiate(loggingOn=True, callbacks=None)
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.setString([vr["scene"], vr["fidelity"]], [scene, "realtime"])
        fmu.exitInitializationMode()
        return fmu
    # no model for the no_contact scene (no model ships for its key): refused at
    # initialization
    try:
        make("untrained", "no_contact")
        res["untrained"] = "initialized"
    except FMICallException as exc:
        res["untrained"] = type(exc).__name__
    fmu = make("trained", scene)
    t, dt, outs = 0.0, 1e-3, []
    fmu.setReal([vr["OOP"]], [0.6])
    for k in range(5):
        fmu.doStep(t, dt)
        t += dt
        outs.append(fmu.getReal([vr["lip_aperture"], vr["lip_protrusion"]]))
    state = fmu.getFMUstate()
    a = []
    for k in range(3):
        fmu.doStep(t + k * dt, dt)
        a.append(fmu.getReal([vr["lip_protrusion"]])[0])
    fmu.setFMUstate(state)
    b = []
    for k in range(3):
        fmu.doStep(t + k * dt, dt)
        b.append(fmu.getReal([vr["lip_protrusion"]])[0])
    res.update(outs=outs, first=a, second=b)
    fmu.terminate()
    fmu.freeInstance()
    json.dump(res, open(out, "w"))
    print("ok")
""")


def test_fmu_carries_a_trained_model_and_refuses_without_one(trained, scene_file, tmp_path):
    build = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest",
                            str(tmp_path), "--rom", str(trained["path"])],
                           capture_output=True, text=True, cwd=tmp_path)
    assert build.returncode == 0, build.stderr
    script, out = tmp_path / "rt.py", tmp_path / "out.json"
    script.write_text(FMPY)
    env = dict(os.environ, FACEFMU_ROM_DIR=str(tmp_path / "empty"))   # not the user's
    run = subprocess.run([sys.executable, str(script), str(tmp_path / "FaceFMU.fmu"),
                          str(out), str(scene_file)], capture_output=True, text=True,
                         cwd=tmp_path, timeout=600, env=env)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    res = json.loads(out.read_text())
    assert res["untrained"] == "FMICallException"
    # fmpy's default logger prints the FMU's log messages
    assert "no trained realtime model for scene 'no_contact'" in run.stdout
    assert "rom_train.py --scene no_contact" in run.stdout
    assert len(res["outs"]) == 5 and res["outs"][-1][1] != 0.0
    assert res["first"] == res["second"]                     # a rollback repeats exactly


def test_realtime_hands_over_to_the_full_model_when_the_jaw_opens(trained, scene_file,
                                                                  monkeypatch):
    """A model trained with the jaw closed (the tiny `trained`): a closed jaw keeps the
    reduced model; an open one is outside its envelope, so the run goes on with the full
    model, with a TrustWarning naming the input, and the jaw opens the lips."""
    from solver.rom.simulation import ReducedSimulation, TrustWarning
    from solver.entry import open_simulation
    monkeypatch.setenv("FACEFMU_ROM_DIR", str(trained["folder"]))
    sim = open_simulation(scene_file, loaded_anatomy=trained["full"].anatomy)
    assert isinstance(sim, ReducedSimulation)
    sim.set_activations({"OOP": 0.3})
    sim.set_jaw(0.0, 0.0)
    assert sim.step(0.005).converged and sim.mode == "rom"
    rest = sim.outputs()
    assert rest["incisor_opening"] == 0.0
    state = sim.get_state()
    with pytest.warns(TrustWarning, match="jaw_opening = 6 deg is outside its training"):
        sim.set_inputs({"OOP": 0.3}, jaw=(6.0, 0.0))           # the FMU's path
    assert sim.mode == "full"
    sim.set_state(state)
    assert sim.mode == "rom"
    with pytest.warns(TrustWarning, match="jaw_opening = 6 deg is outside its training"):
        sim.set_jaw(6.0)
    assert sim.mode == "full"
    assert sim.step(0.015).converged
    out = sim.outputs()
    assert out["incisor_opening"] > 8.0 and out["lip_aperture"] > rest["lip_aperture"] + 3.0
