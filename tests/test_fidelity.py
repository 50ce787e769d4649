"""Fidelity presets (API, scene files, command line, FMU), the dask sweep runner and the
accuracy benchmark (benchmarks/accuracy_vs_time.py, run as a script): its runs, front,
errors and level check.

The sweep tests share one LocalCluster (two worker processes) for the module.
"""

import json
import subprocess
import sys
import textwrap
from dataclasses import fields
from pathlib import Path

import pytest

from solver.core.errors import ParameterError
from solver.app.fidelity import FIDELITIES, PRESETS, apply_fidelity
from solver.app.scene import LEVELS, Scene, SceneError, parse_scene
from solver.app.simulation import Simulation
from solver.face.terms.contact import PENALTY, TEETH_PENALTY

ROOT = Path(__file__).resolve().parents[1]
ACCURACY = ROOT / "benchmarks" / "accuracy_vs_time.py"

pytest.importorskip("dask.distributed")
from solver.sweep import Sweep  # noqa: E402

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
    """A lip_penalty override (here 0.3 N/mm^3 over `balanced`, whose own is PENALTY)
    reaches the LipContact only: its slave stiffnesses are 0.3 / PENALTY times those of the
    preset's, the teeth's stay; a scene file's own lip_penalty is checked."""
    scene = Scene(duration=0.01, lip_contact=True, teeth_contact=True)
    soft = Simulation(scene, fidelity="balanced", lip_penalty=0.3)
    stiff = Simulation(scene, fidelity="balanced")
    assert soft.scene.lip_penalty == 0.3 < PENALTY == stiff.scene.lip_penalty
    terms = [{t.name: t for t in sim.contact} for sim in (soft, stiff)]
    assert terms[0]["lip_contact"].penalty == 0.3
    assert terms[0]["lip_contact"].k == pytest.approx(terms[1]["lip_contact"].k
                                                      * 0.3 / PENALTY)
    teeth = [n for n in terms[0] if n != "lip_contact"]
    assert teeth and all(terms[i][n].penalty == TEETH_PENALTY for n in teeth for i in (0, 1))
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
    assert sim.scene.level == "paper" and sim.scene.substep_tol == PRESETS["balanced"][
        "substep_tol"]
    assert sim.scene.integrator == "bdf2" and sim.integrator.method == "bdf2"
    assert sim.scene.newton_rtol == 1e-7                          # the override wins
    assert sim.face.model.newton_options.rtol == 1e-7
    assert sim.face.model.newton_options.utol == PRESETS["balanced"]["newton_utol"] == 1e-2
    assert sim.scene.rows == 1 and sim.anatomy.half
    assert sim.anatomy.mesh.n_bricks == 3144                     # paper half face, 1 row


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
    from solver.entry import open_simulation

    built = []

    def recording(*args, **kw):
        sim = open_simulation(*args, **kw)
        built.append(sim.scene)
        return sim

    monkeypatch.setattr(run_scene, "open_simulation", recording)
    scene = tmp_path / "tiny.toml"
    scene.write_text('[scene]\nname = "tiny"\nduration = 0.01\n[muscles]\ndriven = ["OOP"]\n'
                     '[outputs]\ninterval = 0.01\n[[schedule]]\nmuscle = "OOP"\nkind = "step"\n'
                     'time = 0.0\nvalue = 0.3\n')
    assert cli.main(["run", str(scene), "--fidelity", "balanced", "--out", str(tmp_path),
                     "--quiet"]) == 0
    assert cli.main(["run", str(scene), "--fidelity", "balanced", "--level", "coarse",
                     "--out", str(tmp_path), "--quiet"]) == 0
    assert [s.level for s in built] == [PRESETS["balanced"]["level"], "coarse"]
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
    fmu = _slave(fidelity="balanced", level="medium")
    fmu.exit_initialization_mode()
    assert fmu.sim.scene.level == "paper"
    assert fmu.sim.scene.substep_tol == PRESETS["balanced"]["substep_tol"]
    assert any("level = 'medium' not used" in m.msg and "balanced" in m.msg
               for m in fmu.log_queue)
    plain = _slave(fidelity="", level="medium", tolerance=2e-3)  # "": the parameters
    plain.exit_initialization_mode()
    assert (plain.sim.scene.level, plain.sim.scene.substep_tol) == ("medium", 2e-3)
    default = _slave()                                        # the FMU's default: balanced
    default.exit_initialization_mode()
    assert default.sim.scene.level == "paper"
    assert default.sim.scene.max_substep == PRESETS["balanced"]["max_substep"]


def test_fmu_keeps_a_scene_files_own_values_unless_the_parameter_is_set(tmp_path):
    scene = tmp_path / "fast.toml"
    scene.write_text('[scene]\nfidelity = "fast"\n[muscles]\ndriven = ["OOP"]\n')
    own = _slave(scene=str(scene))
    own.exit_initialization_mode()
    assert own.fidelity == "fast"
    assert own.sim.scene.substep_tol == PRESETS["fast"]["substep_tol"]
    assert PRESETS["fast"]["substep_tol"] != PRESETS["balanced"]["substep_tol"]
    chosen = _slave(scene=str(scene), fidelity="balanced")
    chosen.exit_initialization_mode()
    assert chosen.sim.scene.substep_tol == PRESETS["balanced"]["substep_tol"]
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
    half, full = sweep.run(tasks, "open_round", progress=False)
    assert (half["label"], full["label"]) == ("half", "full")
    assert half["error"] == full["error"] == ""
    assert 0 < half["ndof"] < full["ndof"]
    for r in (half, full):
        assert all(isinstance(r[k], float) for k in ("build_s", "wall_s", "cpu_s", "rtf"))
        assert r["simulated_s"] == 0.02 and r["rtf"] == pytest.approx(r["wall_s"] / 0.02)
        assert r["peak_mb"] > 0 and r["memory_method"] == "vmhwm"
        assert [round(row["time"], 6) for row in r["rows"]] == [0.0, 0.01, 0.02]
    assert half["worker"].split(":")[1] != str(__import__("os").getpid())   # not here
    assert half["rows"][-1]["lip_protrusion"] == pytest.approx(
        full["rows"][-1]["lip_protrusion"], abs=1e-3)      # a symmetric gesture


def test_a_failing_task_reports_its_error_and_the_sweep_goes_on(sweep):
    bad, good = sweep.run([{"label": "bad", **TINY, "anatomy": "/nowhere"},
                           {"label": "good", **TINY}], "open_round", progress=False)
    assert "/nowhere" in bad["error"]
    assert good["error"] == "" and good["ndof"] > 0


def _accuracy(tmp_path, *args):
    """benchmarks/accuracy_vs_time.py with args, in tmp_path: the finished process."""
    return subprocess.run([sys.executable, str(ACCURACY), *args], capture_output=True,
                          text=True, cwd=tmp_path, timeout=1200)


def _csv(path):
    import csv
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow                   # 66 s on a slow day: out of the default suite
def test_quick_benchmark_exits_0_as_the_error_falls_as_the_level_rises(tmp_path):
    """`accuracy_vs_time.py --quick`: coarse and medium against paper at the default
    tolerances; it exits 1 unless the error falls as the level rises."""
    run = _accuracy(tmp_path, "--quick", "--out", "quick")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]    # 1: it did not
    assert (tmp_path / "quick" / "pareto.png").stat().st_size > 0
    assert (tmp_path / "quick" / "accuracy_vs_time.csv").read_text().count("\n") > 5


# -------------------------------------------------------------- the accuracy benchmark

def test_every_preset_is_a_run_of_the_default_sweep_and_tolerance_runs_tighten_one_knob(
        tmp_path):
    """--list (no runs): every fidelity preset is a run of the default sweep; the
    `balanced at substep_tol X` and `fast at ...` runs differ from their preset's run in a
    tighter substep tolerance alone."""
    run = _accuracy(tmp_path, "--list", "--out", "out")
    assert run.returncode == 0, run.stderr
    runs = _csv(tmp_path / "out" / "runs.csv")
    presets = {r["preset"]: r for r in runs if r["preset"] in FIDELITIES}
    assert set(presets) == set(FIDELITIES)
    knobs = [k for k in runs[0] if k not in ("label", "reference", "fidelity", "preset")]
    tightened = [r for r in runs if " at substep_tol " in r["label"]]
    assert {r["label"].split()[0] for r in tightened} == {"balanced", "fast"}
    for r in tightened:
        own = presets[r["label"].split()[0]]
        assert [k for k in knobs if r[k] != own[k]] == ["substep_tol"]
        assert float(r["substep_tol"]) < float(own["substep_tol"])
        assert r["reference"] == "fine"


def test_the_default_sweep_runs_the_default_scenes_own_settings(tmp_path):
    """--list: the run `default scene` has the default scene's level and solver settings
    (solver/app/scenes/default.toml), against the fine face."""
    from solver.app.simulation import resolve_scene
    run = _accuracy(tmp_path, "--list", "--out", "out")
    assert run.returncode == 0, run.stderr
    row = next(r for r in _csv(tmp_path / "out" / "runs.csv") if r["label"] == "default scene")
    own = resolve_scene("default")
    assert row["reference"] == "fine" and row["level"] == own.level
    for key in ("integrator", "substep_tol", "max_substep", "newton_rtol", "newton_utol"):
        value = getattr(own, key)
        assert (row[key] == value) if isinstance(value, str) else \
            float(row[key]) == pytest.approx(value), key


def test_replot_marks_the_front_fits_the_rate_and_names_the_presets(tmp_path):
    """--replot of a table: the Pareto front of the generic-face runs (a run slower and
    less accurate than another is off it), the rate p of err ~ h^p over the level study
    (errors 0.01 h^2: p = 2) and the run at a preset's knobs named after it."""
    def row(label, level, h, wall, err, **knobs):
        return {"label": label, "fidelity": "", "anatomy": "generic", "level": level,
                "rows": 2, "half": True, "substep_tol": 1e-3, "max_substep": 5e-3,
                "newton_rtol": 1e-6, "newton_utol": 1e-5, "lip_penalty": PENALTY,
                "formulation": "mean_dilatation", "stiffening": True, "ndof": 100,
                "h_mm": h, "wall_s": wall, "cpu_s": wall, "rtf": wall / 0.1,
                "peak_mb": 10.0, "reference": "fine", "error": "",
                **({"err_aperture_mm": err, "err_protrusion_mm": err / 2, "err_mm": err}
                   if err is not None else {}), **knobs}
    balanced = {k: v for k, v in PRESETS["balanced"].items() if k != "level"}
    table = [row("fine", "fine", 0.5, 100.0, None, reference="-"),
             row("coarse 2 rows", "coarse", 4.0, 1.0, 0.16),
             row("medium 2 rows", "medium", 2.0, 4.0, 0.04),
             row("paper 2 rows", "paper", 1.0, 16.0, 0.01),
             row("like balanced", PRESETS["balanced"]["level"], 2.0, 5.0, 0.035, **balanced),
             row("coarse loose", "coarse", 4.0, 2.0, 0.5, rows=1, substep_tol=1e-2)]
    import csv
    (tmp_path / "old").mkdir()
    with open(tmp_path / "old" / "accuracy_vs_time.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for r in table for k in r)))
        w.writeheader()
        w.writerows(table)
    run = _accuracy(tmp_path, "--replot", "old", "--doc", "docs/sweep.md", "--img",
                    "docs/img/pareto.png")
    assert run.returncode == 0, run.stderr
    page = (tmp_path / "docs" / "sweep.md").read_text()
    assert ("`python benchmarks/accuracy_vs_time.py --replot old --doc docs/sweep.md --img "
            "docs/img/pareto.png`") in page
    assert "the figures of the sweep in old, replotted" in page
    assert "\nmedium 2 rows | fine | 2 | 100 | 4 | 4 | 40 | 0.04 | 0.02 | yes | \n" in page
    assert "\nlike balanced | fine | " in page and page.count("| yes |") == 4
    assert (tmp_path / "docs" / "img" / "pareto.png").stat().st_size > 0
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import accuracy_vs_time
    rows, rates, falls = accuracy_vs_time.level_study(
        accuracy_vs_time.read_table(tmp_path / "old" / "accuracy_vs_time.csv"))
    assert [r["label"] for r in rows] == ["coarse 2 rows", "medium 2 rows", "paper 2 rows"]
    assert rates == pytest.approx({"err_aperture_mm": 2.0, "err_protrusion_mm": 2.0,
                                   "err_mm": 2.0})
    assert falls
    out = {r["label"]: r for r in _csv(tmp_path / "old" / "accuracy_vs_time.csv")}
    assert {k for k, r in out.items() if r["pareto"] == "True"} == {
        "coarse 2 rows", "medium 2 rows", "paper 2 rows", "like balanced"}
    assert out["coarse loose"]["pareto"] == "False"
    assert out["like balanced"]["preset"] == "balanced"
    assert (tmp_path / "old" / "pareto.png").stat().st_size > 0


def test_a_runs_errors_are_taken_against_its_reference(tmp_path):
    """--only with --merge: a run (coarse loose, 0.01 s) against its reference (fine)
    taken from an earlier sweep's records, not run again: the errors are the largest
    differences over the record times."""
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    ref = [{"time": round(0.005 * i, 6), "lip_aperture": 1.0 + 0.1 * i,
            "lip_protrusion": -0.01 * i} for i in range(3)]
    (earlier / "records.json").write_text(json.dumps({"fine": ref}))
    (earlier / "accuracy_vs_time.csv").write_text("label,reference,error\n")
    run = _accuracy(tmp_path, "--duration", "0.01", "--workers", "1", "--only",
                    "coarse loose", "--merge", "earlier", "--out", "out")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    rows = json.loads((tmp_path / "out" / "records.json").read_text())["coarse loose"]
    assert [r["time"] for r in rows] == pytest.approx([r["time"] for r in ref])
    (row,) = _csv(tmp_path / "out" / "accuracy_vs_time.csv")
    assert (row["label"], row["reference"], row["error"]) == ("coarse loose", "fine", "")
    for key, col in (("lip_aperture", "err_aperture_mm"),
                     ("lip_protrusion", "err_protrusion_mm")):
        want = max(abs(a[key] - b[key]) for a, b in zip(rows, ref))
        assert float(row[col]) == pytest.approx(want)
    assert float(row["err_mm"]) == max(float(row["err_aperture_mm"]),
                                       float(row["err_protrusion_mm"]))
