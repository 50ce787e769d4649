"""The built FMU through fmpy: validation, simulate_fmu, stepwise, rollback, refusals.

CI builds the FMU from scratch (session fixture) and tests the built file. Each fmpy run
goes in its own process: pythonfmu loads every FMU into one interpreter, and a solver
package already imported by the test process would win over the FMU's own copy.
"""

import json
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest

from conftest import SCRIPTS


def _run(script, fmu, tmp_path, *args, timeout=600):
    out = tmp_path / "out.json"
    run = subprocess.run([sys.executable, str(SCRIPTS / script), str(fmu), str(out), *args],
                         capture_output=True, text=True, timeout=timeout, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-4000:]
    return json.loads(out.read_text()), run.stdout


def test_model_description_passes_fmpy_validate_and_has_units(fmu):
    from fmpy.validation import validate_fmu
    assert validate_fmu(str(fmu)) == []
    root = ET.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))
    assert {u.get("name") for u in root.find("UnitDefinitions")} == {"mm", "s", "N", "deg",
                                                                    "1"}
    assert root.find("CoSimulation").get("needsExecutionTool") == "false"
    assert root.find("CoSimulation").get("canGetAndSetFMUstate") == "true"
    assert root.find("DefaultExperiment") is not None
    variables = {v.get("name"): v for v in root.find("ModelVariables")}
    oop = variables["OOP"]
    assert oop.get("causality") == "input" and "orbicularis" in oop.get("description")
    assert (oop[0].get("unit"), oop[0].get("min"), oop[0].get("max"), oop[0].get("start")) == \
        ("1", "0", "1", "0")
    assert variables["lip_aperture"][0].get("unit") == "mm"
    for p in ("anatomy", "level", "scene", "half_face", "tolerance", "max_substep", "fidelity"):
        assert variables[p].get("causality") == "parameter", p
    outputs = root.find("ModelStructure").find("Outputs")
    assert len(outputs) == 12 and all(u.get("dependencies") == "" for u in outputs)
    assert variables["rom_fallbacks"].get("causality") == "output"
    assert variables["rom_full_time"].get("causality") == "output"
    assert variables["contact_force"][0].get("unit") == "N"
    jaw = variables["jaw_opening"]
    assert jaw.get("causality") == "input"
    assert (jaw[0].get("unit"), jaw[0].get("min"), jaw[0].get("max")) == ("deg", "0", "20")
    assert variables["jaw_protrusion"][0].get("unit") == "mm"
    assert variables["incisor_opening"][0].get("unit") == "mm"


def _script(name):
    """An installed console script: beside this interpreter (a venv that is not activated
    has its scripts off PATH), else on PATH; None if neither."""
    here = Path(sys.executable).parent / name
    return str(here) if here.is_file() else shutil.which(name)


FMUTOOL = _script("fmutool")


@pytest.mark.skipif(FMUTOOL is None, reason="fmu-manipulation-toolbox absent")
def test_fmutool_check(fmu):
    run = subprocess.run([FMUTOOL, "-input", str(fmu), "-check"], capture_output=True,
                         text=True, timeout=120)
    text = run.stdout + run.stderr
    assert run.returncode == 0 and "compliant" in text and "ERROR" not in text, text


def test_simulate_fmu_with_input_signals(fmu, tmp_path):
    res, _ = _run("simulate.py", fmu, tmp_path)
    assert res["time"][0] == 0.0 and abs(res["time"][-1] - 0.1) < 1e-9
    width, protrusion = res["lip_width"], res["lip_protrusion"]
    assert protrusion[0] == 0.0 and abs(protrusion[5]) > 0.05      # OOP moved the lips
    assert width[5] < width[0]                                     # OOP narrows the mouth
    assert width[-1] > width[5]                                    # then RIS widens it
    assert all(n > 0 for n in res["newton_iterations"][2:])      # [1]: a step at rest


def test_stepwise_rollback_refusals_and_two_instances(fmu, tmp_path):
    res, stdout = _run("stepwise.py", fmu, tmp_path)
    first, second, third = res["rollback"]
    assert first == second == third                     # identical after rollback
    assert first["lip_protrusion"] != res["after_3"]["lip_protrusion"]
    assert [r[1] for r in res["refused"]] == [2] * 6      # each bad step: fmi2Discard
    for needle in ("OOP = nan", "OOP = 1.5", "RIS = inf", "step size -0.01",
                   "step size 0.0", "starts at t = 0.53"):
        assert needle in stdout, needle
    assert res["after_refusals"]["substeps"] > 0         # the next valid step works
    assert res["second_instance"]["lip_protrusion"] != 0.0


@pytest.fixture(scope="module")
def generic_probe():
    """The FMU's default model (the default scene at the `balanced` preset: the generic half
    face's mesh at that preset's level and rows) and its penetration probe."""
    from solver.face.anatomy.load import load_anatomy
    from solver.app.fidelity import fidelity_overrides
    from solver.validation.stability import Probe
    preset = fidelity_overrides("balanced")
    return Probe(load_anatomy("generic", preset["level"], preset["half"], preset["rows"]))


def _penetrations(probe, state_files):
    import numpy as np
    depths = []
    for path in state_files:
        with np.load(path) as z:
            u = z["sim.u"].reshape(-1, 3)
        depths.append(probe.penetrations(u))
    return depths


def test_the_default_fmu_keeps_the_lips_in_front_of_the_teeth(fmu, tmp_path, generic_probe):
    """OOP = 1 for 0.15 s with the FMU's default parameters: the lips protrude, and no lip
    node goes behind the teeth (measured here, outside the FMU, on its serialized states
    every 50 ms)."""
    from solver.validation.stability import CONTACT_TOLERANCE
    res, stdout = _run("held_activation.py", fmu, tmp_path, "OOP", "0.15")
    rows = res["rows"]
    assert rows[-1]["lip_protrusion"] > 0.2                   # OOP protrudes the lips
    assert max(r["contact_force"] for r in rows) > 0.0        # contact carries load
    assert "interpenetrate" not in stdout
    depths = _penetrations(generic_probe, res["states"])
    assert len(depths) == 3
    assert max(t for _, t in depths) <= CONTACT_TOLERANCE, depths


def test_a_scene_without_contact_is_named_and_warned_about(fmu, tmp_path, generic_probe):
    """The no_contact scene is there when asked for by name, and its warning is logged:
    OOP = 1 pulls the lips back into the teeth."""
    res, stdout = _run("held_activation.py", fmu, tmp_path, "OOP", "0.1", "no_contact")
    assert "scene 'no_contact' leaves out lip/lip and lip/teeth contact" in stdout
    assert res["rows"][-1]["contact_force"] == 0.0


def test_a_step_the_solver_cannot_take_is_refused_and_the_state_kept(fmu, tmp_path):
    scene = tmp_path / "too_strong.toml"
    scene.write_text('[muscles]\ndriven = ["OOP"]\nforce_scale = { OOP = 300.0 }\n'
                     '[solver]\nmax_substep = 0.005\nmin_substep = 0.004\n')
    res, stdout = _run("nonconvergence.py", fmu, tmp_path, str(scene))
    assert res["status"] == 2 and res["unchanged"]
    assert re.search(r"did not converge after [1-9]\d* cutbacks", stdout)   # logged, counted
    assert res["after"][0] != 0.0                        # the next valid step moved the lips


def test_the_jaw_through_the_fmu_opens_rolls_back_exactly_and_refuses_bad_values(fmu,
                                                                                  tmp_path):
    """jaw_opening and jaw_protrusion as FMU inputs: the incisor opening follows the
    geometry (7.945 deg: 12 mm), the lips open with it, a jaw step repeated after a
    rollback (getFMUstate, and its serialized bytes) gives identical outputs, and NaN,
    inf or out-of-range jaw inputs are refused with fmi2Discard, a message naming the
    input, and the outputs unchanged."""
    res, stdout = _run("jaw.py", fmu, tmp_path)
    opened = res["opening"]
    assert res["rest"]["incisor_opening"] == 0.0
    assert abs(opened[-1]["incisor_opening"] - 12.0) < 0.01
    assert opened[-1]["lip_aperture"] > res["rest"]["lip_aperture"] + 5.0
    first, second, third = res["rollback"]
    assert first == second == third
    assert first["incisor_opening"] != opened[-1]["incisor_opening"]
    assert all(status == 2 and same for _, status, same in res["refused"]), res["refused"]
    for needle in ("jaw_opening = nan", "jaw_opening = 25.0 deg", "jaw_opening = -1.0 deg",
                   "jaw_protrusion = inf", "jaw_protrusion = 11.0 mm"):
        assert needle in stdout, needle
    assert abs(res["after_refusals"]["incisor_opening"] - 12.0) < 0.01
