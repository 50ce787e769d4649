"""Fidelity presets (API, scene files, command line, FMU), the dask sweep runner and the
accuracy benchmark's level check (the check of `accuracy_vs_time.py --quick`).

The sweep tests share one LocalCluster (two worker processes) for the module.
"""

import json
import subprocess
import sys
import textwrap
from dataclasses import fields
from pathlib import Path

import pytest

from solver.errors import ParameterError
from solver.fidelity import FIDELITIES, LIP_SOFT, PRESETS, apply_fidelity
from solver.scene import LEVELS, Scene, SceneError, parse_scene
from solver.simulation import Simulation
from solver.terms.contact import PENALTY

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))                    # benchmarks/ is not installed

pytest.importorskip("dask.distributed")
from benchmarks import accuracy_vs_time as avt  # noqa: E402
from benchmarks.sweep import Sweep  # noqa: E402

TINY = {"level": "coarse", "half": True, "duration": 0.02, "interval": 0.01}


# ------------------------------------------------------------------------ presets

def test_presets_set_only_numerical_scene_fields_and_leave_the_model():
    names = {f.name for f in fields(Scene)}
    base = Scene(name="x", driven=("OOP",), duration=0.2, stiffening=False,
                 teeth_contact=True)
    for name in FIDELITIES:
        assert set(PRESETS[name]) <= names - {"stiffening", "lip_contact", "teeth_contact",
                                              "driven", "anatomy", "analysis"}
        scene = apply_fidelity(base, name)
        assert all(getattr(scene, k) == v for k, v in PRESETS[name].items())
        assert (scene.name, scene.driven, scene.duration, scene.stiffening,
                scene.teeth_contact) == ("x", ("OOP",), 0.2, False, True)
    assert base.level == "coarse" and base.substep_tol == 1e-3     # base unchanged


def test_presets_rise_in_resolution_and_do_not_loosen_tolerances_in_order():
    mesh = [(LEVELS.index(PRESETS[n]["level"]), PRESETS[n]["rows"]) for n in FIDELITIES]
    assert mesh == sorted(mesh) and len(set(mesh)) == len(mesh)
    for key in ("substep_tol", "max_substep", "newton_rtol", "newton_utol"):
        values = [PRESETS[n][key] for n in FIDELITIES]
        assert values == sorted(values, reverse=True), key
    penalties = [PRESETS[n]["lip_penalty"] for n in FIDELITIES]   # stiffer: tighter
    assert penalties == sorted(penalties) and penalties[-1] == PENALTY


def test_the_lip_penalty_of_a_preset_reaches_the_lip_contact_only():
    """`balanced` softens the lip/lip penalty (a numerical setting,
    docs/dev-notes/fast_path.md): its LipContact's slave stiffnesses are LIP_SOFT /
    PENALTY times those of the scene's default, the teeth's stay; a scene file's own
    lip_penalty is checked."""
    scene = Scene(duration=0.01, lip_contact=True, teeth_contact=True)
    soft = Simulation(scene, fidelity="balanced")
    stiff = Simulation(scene, fidelity="balanced", lip_penalty=PENALTY)
    assert soft.scene.lip_penalty == LIP_SOFT < PENALTY == stiff.scene.lip_penalty
    terms = [{t.name: t for t in sim.contact} for sim in (soft, stiff)]
    assert terms[0]["lip_contact"].penalty == LIP_SOFT
    assert terms[0]["lip_contact"].k == pytest.approx(terms[1]["lip_contact"].k
                                                      * LIP_SOFT / PENALTY)
    teeth = [n for n in terms[0] if n != "lip_contact"]
    assert teeth and all(terms[0][n].penalty == PENALTY for n in teeth)
    assert parse_scene({"solver": {"lip_penalty": 0.5}}).lip_penalty == 0.5
    for bad in (0.0, -1.0, float("nan"), "stiff"):
        with pytest.raises(SceneError) as info:
            parse_scene({"solver": {"lip_penalty": bad}}, source="s.toml")
        assert "solver.lip_penalty" in str(info.value)


def test_unknown_fidelity_is_refused_naming_it_and_the_allowed():
    with pytest.raises(ParameterError) as info:
        Simulation(Scene(), fidelity="ultra")
    assert "'ultra'" in str(info.value)
    assert all(n in str(info.value) for n in FIDELITIES)


def test_simulation_applies_the_preset_under_its_overrides():
    sim = Simulation(Scene(duration=0.01), fidelity="balanced", newton_rtol=1e-7)
    assert sim.scene.level == "medium" and sim.scene.substep_tol == PRESETS["balanced"][
        "substep_tol"]
    assert sim.scene.newton_rtol == 1e-7                          # the override wins
    assert sim.face.model.newton_options.rtol == 1e-7
    assert sim.face.model.newton_options.utol == PRESETS["balanced"]["newton_utol"] == 1e-2
    assert sim.scene.rows == 2 and sim.anatomy.half
    assert sim.anatomy.mesh.n_bricks == 2 * 1449                 # medium half face, 2 rows


def test_a_preset_leaves_an_ansys_face_its_own_mesh():
    scene = apply_fidelity(Scene(anatomy="/some/face"), "balanced")
    assert scene.rows is None and scene.substep_tol == PRESETS["balanced"]["substep_tol"]
    scene = parse_scene({"scene": {"fidelity": "balanced"}, "anatomy": {"source": "/f"}})
    assert scene.rows is None


def test_scene_file_fidelity_key_gives_defaults_that_its_own_keys_override():
    scene = parse_scene({"scene": {"fidelity": "accurate"}})
    assert all(getattr(scene, k) == v for k, v in PRESETS["accurate"].items())
    scene = parse_scene({"scene": {"fidelity": "accurate"}, "anatomy": {"level": "coarse"},
                         "solver": {"newton_rtol": 1e-3}})
    assert (scene.level, scene.newton_rtol) == ("coarse", 1e-3)
    assert scene.substep_tol == PRESETS["accurate"]["substep_tol"]
    assert parse_scene({"solver": {"newton_utol": 2e-4}}).newton_utol == 2e-4
    with pytest.raises(SceneError) as info:
        parse_scene({"solver": {"newton_utol": 0.0}}, source="s.toml")
    assert "solver.newton_utol" in str(info.value)
    with pytest.raises(SceneError) as info:
        parse_scene({"scene": {"fidelity": "ultra"}}, source="s.toml")
    assert "scene.fidelity" in str(info.value) and "'ultra'" in str(info.value)
    assert all(n in str(info.value) for n in FIDELITIES)


# ------------------------------------------------------------------- command line

def test_cli_run_fidelity_applies_the_preset_and_level_wins(tmp_path, monkeypatch, capsys):
    from facefmu import cli, run_scene

    built = []

    class Recording(Simulation):
        def __init__(self, *args, **kw):
            super().__init__(*args, **kw)
            built.append(self.scene)

    monkeypatch.setattr(run_scene, "Simulation", Recording)
    scene = tmp_path / "tiny.toml"
    scene.write_text('[scene]\nname = "tiny"\nduration = 0.01\n[muscles]\ndriven = ["OOP"]\n'
                     '[outputs]\ninterval = 0.01\n[[schedule]]\nmuscle = "OOP"\nkind = "step"\n'
                     'time = 0.0\nvalue = 0.3\n')
    assert cli.main(["run", str(scene), "--fidelity", "balanced", "--out", str(tmp_path),
                     "--quiet"]) == 0
    assert cli.main(["run", str(scene), "--fidelity", "balanced", "--level", "coarse",
                     "--out", str(tmp_path), "--quiet"]) == 0
    assert [s.level for s in built] == ["medium", "coarse"]
    assert all(s.substep_tol == PRESETS["balanced"]["substep_tol"] for s in built)
    assert (tmp_path / "tiny.csv").is_file()
    with pytest.raises(SystemExit) as info:
        cli.main(["run", str(scene), "--fidelity", "ultra"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "'ultra'" in err and all(n in err for n in FIDELITIES)


# --------------------------------------------------------------------------- FMU

def _slave(**params):
    from facefmu.facefmu_slave import FaceFMU
    fmu = FaceFMU(instance_name="test")
    for k, v in params.items():
        fmu._set_parameter(k, v)                    # what a master's set call does
    return fmu


def test_fmu_declares_a_fidelity_string_parameter_defaulting_to_balanced():
    root = _slave().to_xml()
    var = next(v for v in root.find("ModelVariables") if v.get("name") == "fidelity")
    assert var.get("causality") == "parameter" and var.get("variability") == "fixed"
    assert var[0].tag == "String" and var[0].get("start") == "balanced"
    assert all(n in var.get("description") for n in FIDELITIES)


def test_fmu_fidelity_preset_sets_level_and_tolerances_and_warns_for_ignored_parameters():
    fmu = _slave(fidelity="balanced", level="paper")
    fmu.exit_initialization_mode()
    assert fmu.sim.scene.level == "medium"
    assert fmu.sim.scene.substep_tol == PRESETS["balanced"]["substep_tol"]
    assert any("level = 'paper' not used" in m.msg and "balanced" in m.msg
               for m in fmu.log_queue)
    plain = _slave(fidelity="", level="medium", tolerance=2e-3)  # "": the parameters
    plain.exit_initialization_mode()
    assert (plain.sim.scene.level, plain.sim.scene.substep_tol) == ("medium", 2e-3)
    default = _slave()                                        # the FMU's default: balanced
    default.exit_initialization_mode()
    assert default.sim.scene.level == "medium"
    assert default.sim.scene.max_substep == PRESETS["balanced"]["max_substep"]


def test_fmu_keeps_a_scene_files_own_values_unless_the_parameter_is_set(tmp_path):
    scene = tmp_path / "fast.toml"
    scene.write_text('[scene]\nfidelity = "fast"\n[muscles]\ndriven = ["OOP"]\n')
    own = _slave(scene=str(scene))
    own.exit_initialization_mode()
    assert own.fidelity == "fast"
    assert own.sim.scene.max_substep == PRESETS["fast"]["max_substep"]
    assert PRESETS["fast"]["max_substep"] != PRESETS["balanced"]["max_substep"]
    chosen = _slave(scene=str(scene), fidelity="balanced")
    chosen.exit_initialization_mode()
    assert chosen.sim.scene.max_substep == PRESETS["balanced"]["max_substep"]
    paper = tmp_path / "paper.toml"
    paper.write_text('[anatomy]\nlevel = "paper"\n[solver]\nsubstep_tol = 0.02\n'
                     '[muscles]\ndriven = ["OOP"]\n')
    kept = _slave(scene=str(paper), fidelity="")
    kept.exit_initialization_mode()
    assert (kept.sim.scene.level, kept.sim.scene.substep_tol) == ("paper", 0.02)
    overridden = _slave(scene=str(paper), fidelity="", level="coarse", tolerance=5e-3)
    overridden.exit_initialization_mode()
    assert (overridden.sim.scene.level, overridden.sim.scene.substep_tol) == ("coarse", 5e-3)


def test_fmu_unknown_fidelity_fails_initialization_with_a_logged_message():
    fmu = _slave(fidelity="ultra")
    with pytest.raises(ParameterError):
        fmu.exit_initialization_mode()
    errors = [m.msg for m in fmu.log_queue if m.status.name == "error"]
    assert len(errors) == 1 and "fidelity 'ultra'" in errors[0]
    assert all(n in errors[0] for n in FIDELITIES)


FMPY_SCRIPT = textwrap.dedent("""
    import json, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    path, out = sys.argv[1], sys.argv[2]
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzip, res = extract(path), {}
    for value in ("fast", "ultra"):
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip, instanceName=value,
                        modelIdentifier=md.coSimulation.modelIdentifier)
        fmu.instantiate(loggingOn=True, callbacks=None)
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.setString([vr["fidelity"]], [value])
        try:
            fmu.exitInitializationMode()
            fmu.setReal([vr["OOP"]], [0.5])
            fmu.doStep(0.0, 0.01)
            res[value] = fmu.getReal([vr["lip_protrusion"]])[0]
            fmu.terminate()
        except Exception as exc:
            res[value] = type(exc).__name__
        fmu.freeInstance()
    json.dump(res, open(out, "w"))
""")


def test_built_fmu_takes_the_fidelity_parameter_through_fmpy(tmp_path):
    build = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest",
                            str(tmp_path)], capture_output=True, text=True, cwd=tmp_path)
    assert build.returncode == 0, build.stderr
    script, out = tmp_path / "fidelity.py", tmp_path / "out.json"
    script.write_text(FMPY_SCRIPT)
    run = subprocess.run([sys.executable, str(script), str(tmp_path / "FaceFMU.fmu"),
                          str(out)], capture_output=True, text=True, cwd=tmp_path,
                         timeout=300)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    res = json.loads(out.read_text())
    assert isinstance(res["fast"], float) and res["fast"] != 0.0   # OOP moved the lips
    assert res["ultra"] == "FMICallException"                      # fmi2Fatal at init


# ------------------------------------------------------------------------- sweeps

@pytest.fixture(scope="module")
def sweep():
    with Sweep(n_workers=2) as s:
        yield s


def test_two_task_sweep_on_a_local_cluster_reports_each_run_with_its_own_costs(sweep):
    tasks = [{"label": "half", **TINY}, {"label": "full", **TINY, "half": False}]
    half, full = sweep.run(tasks, avt.gesture(duration=0.02), progress=False)
    assert (half["label"], full["label"]) == ("half", "full")
    assert half["error"] == full["error"] == ""
    assert 0 < half["ndof"] < full["ndof"]
    for r in (half, full):
        assert r["wall_s"] > 0 and r["cpu_s"] > 0 and r["peak_mb"] > 0
        assert r["memory_method"] == "vmhwm"
        assert r["rtf"] == pytest.approx(r["wall_s"] / 0.02)
        assert [round(row["time"], 6) for row in r["rows"]] == [0.0, 0.01, 0.02]
    assert half["worker"].split(":")[1] != str(__import__("os").getpid())   # not here
    assert half["rows"][-1]["lip_protrusion"] == pytest.approx(
        full["rows"][-1]["lip_protrusion"], abs=1e-3)      # a symmetric gesture


def test_a_failing_task_reports_its_error_and_the_sweep_goes_on(sweep):
    bad, good = sweep.run([{"label": "bad", **TINY, "anatomy": "/nowhere"},
                           {"label": "good", **TINY}], avt.gesture(duration=0.02),
                          progress=False)
    assert "/nowhere" in bad["error"]
    assert good["error"] == "" and good["ndof"] > 0


@pytest.mark.slow                   # 66 s on a slow day: out of the default suite
def test_quick_level_study_error_falls_as_the_level_rises(sweep):
    """The check of `accuracy_vs_time.py --quick`: its level study (coarse and medium
    against paper at the default tolerances) over its duration."""
    specs = [s for s in avt.sweep_specs(quick=True) if s["label"] in LEVELS]
    results = avt.run_specs(sweep, specs, avt.QUICK_DURATION, progress=False)
    rows, rates, falls = avt.level_study(avt.evaluate(specs, results))
    assert [r["level"] for r in rows] == ["coarse", "medium"]
    assert falls, [(r["level"], r["err_mm"]) for r in rows]
    assert rates["err_mm"] > 0


@pytest.mark.slow
def test_quick_benchmark_runs_and_exits_0(tmp_path):
    assert avt.main(["--quick", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "pareto.png").stat().st_size > 0
    assert (tmp_path / "accuracy_vs_time.csv").read_text().count("\n") > 5


# -------------------------------------------------------------- benchmark helpers

def test_errors_are_taken_against_each_runs_reference():
    def result(values):
        return {"error": "", "ndof": 3, "wall_s": 1.0, "cpu_s": 1.0, "rtf": 10.0,
                "peak_mb": 1.0, "volume_mm3": 8.0, "bricks": 1,
                "rows": [{"time": 0.01 * i, "lip_aperture": a, "lip_protrusion": p}
                         for i, (a, p) in enumerate(values)]}

    specs = [avt.spec("ref", None), avt.spec("a", "ref"), avt.spec("b", "bad"),
             avt.spec("bad", None)]
    results = [result([(1, 0), (2, 1)]), result([(1.5, 0), (2, 0.75)]),
               result([(1, 0), (2, 1)]), {"error": "boom"}]
    ref, a, b, bad = avt.evaluate(specs, results)
    assert "err_mm" not in ref and ref["h_mm"] == 2.0
    assert (a["err_aperture_mm"], a["err_protrusion_mm"], a["err_mm"]) == (0.5, 0.25, 0.5)
    assert "boom" in b["error"] and "err_mm" not in b
    assert bad["error"] == "boom"


def test_pareto_mask_and_rate_fit():
    assert avt.pareto_mask([1, 2, 3, 4], [5, 1, 2, 0.5]).tolist() == [True, True, False, True]
    p, c = avt.fit_rate([1.0, 2.0, 4.0], [0.3, 1.2, 4.8])
    assert p == pytest.approx(2.0) and c == pytest.approx(0.3)


def test_every_preset_is_a_run_of_the_default_sweep():
    specs = avt.sweep_specs(quick=False)
    table = [{k: s[k] for k in ("label", *avt.KNOBS)} for s in specs]
    avt.mark_presets(table)
    assert {r.get("preset") for r in table} >= set(FIDELITIES)


def test_tolerance_runs_differ_from_their_preset_in_a_tighter_substep_tolerance_alone():
    specs = avt.tolerance_specs("fine")
    assert {s["label"].split()[0] for s in specs} == {"balanced", "fast"}
    for s in specs:
        knobs = avt.with_rows({**avt.DEFAULT, **PRESETS[s["label"].split()[0]]})
        assert {k for k in avt.KNOBS if s[k] != knobs[k]} == {"substep_tol"}
        assert s["substep_tol"] < knobs["substep_tol"] and s["ref"] == "fine"
