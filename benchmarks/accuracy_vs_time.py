"""What accuracy costs in time: lip-output error against run time over the solver's knobs.

    python benchmarks/accuracy_vs_time.py [--quick] [--duration S] [--out DIR]
                                          [--scheduler ADDRESS] [--workers 2]
                                          [--only LABEL,LABEL [--merge DIR]]
                                          [--cost wall|cpu] [--replot DIR] [--list]
                                          [--doc FILE.md] [--img FILE.png]

Scene (`gesture`, the built-in scene open_round): transient, the generic face, teeth and lip contact on. LLSAN and DLI
open the lips (0 to 0.8 over 0-0.04 s), then OOP and RIS round and retract them (OOP 0 to
0.6, RIS 0 to 0.5 over 0.04-0.08 s), held to 0.1 s; lip aperture and protrusion recorded
every 5 ms. The lips stay apart (aperture 0.4 mm at rest, then opening), so lip/lip
contact is built and searched but never closes; the lips press on the teeth. (A closing
gesture would clamp the aperture at 0, which hides its error.)

Runs (each an independent task of solver.sweep; the default sweep):
* level study at the DEFAULT tolerances: coarse, medium, paper and fine half faces, all
  with two brick rows per layer through the thickness (rows = 2, the fine level's own),
  so that the levels refine the mesh in the plane alone; the fine one ("fine") is the
  reference run of every generic-face run. (The levels' own meshes refine unevenly: one
  row per layer up to paper, two at fine; against fine their errors do not fall
  monotonically.) The fine face at TIGHT tolerances would cost twice its DEFAULT run
  and more than the 30 minutes of the sweep; the time-stepping and Newton error of the
  DEFAULT tolerances shows on the coarser levels, where TIGHT, DEFAULT and LOOSE runs
  differ (and on the reference face against its TIGHT run).
* coarse, medium and paper with their own rows (one per layer, the paper's) at DEFAULT
  and LOOSE tolerances, medium also at TIGHT, and medium with two rows at LOOSE: what the
  thickness resolution and the tolerances cost in error;
* the full face and stiffening off on the medium level; formulation "full" on the coarse
  and the medium half face. (No full-face, TIGHT or stiffening-off run of the coarse
  level: the medium level's show those effects, and the sweep keeps within 30 minutes.)
* the fidelity presets of solver.app.fidelity (a run is added for a preset no row matches;
  none for a preset finer than the reference);
* the default scene's own settings (solver/app/scenes/default.toml: its level and
  [solver] section; label "default scene"): the point of a run without a preset;
* the `balanced` preset at substep error tolerances 1e-2, 2e-2 and 3e-2 mm, and `fast`
  at 1e-2 mm, the rest of each preset as it is (labels "balanced at substep_tol 0.01"
  and so on): what the presets' 5e-2 mm costs;
* the reduced-order fidelity `realtime` (solver.rom: its full-order knobs, coarse half face,
  LOOSE) with the model trained on open_round (`python benchmarks/rom_train.py --scene
  open_round`; left out, with that command printed, where no model is trained);
* the reference (ANSYS) face at its own resolution (../shared/data/reference-face or
  $FACEFMU_REFERENCE_FACE; skipped where absent): at DEFAULT, LOOSE and full face against
  itself at TIGHT, since it has no finer mesh (its errors are time-stepping, Newton and
  half-face errors only).

Error of a run: the largest difference over the recorded times (mm) between the run and its
reference in lip aperture and in protrusion; err_mm is the larger of the two.

Cost: wall time of Simulation.run() in the task (build time apart) on one core next to one
other task; cpu_s, the worker's CPU time over it, is the wall time on an idle core (`--cost
cpu` takes it for the front and plot where other jobs load the machine); peak memory of the
task (VmHWM reset per task, see solver/sweep.py); DOF; real-time factor rtf = wall time
/ simulated time (1 = real time).

Level study: the generic-face runs that differ from the reference run in their level
alone; h = (mesh volume / bricks)^(1/3) (mm); the rate p of err ~ h^p fitted by least
squares in log-log over them (the reference's own error is left out, so p is optimistic
as the levels near it).

--only LABELS runs those runs and their references; with --merge DIR the references
already in DIR (an earlier sweep's output) are not run again, and the table and records
written to --out are DIR's with the runs of this call added or replaced (to place a new
run, such as the realtime one, without running the whole sweep again; the rows keep the
figures of the call that ran them).

--quick: the sweep shrunk to run in under 3 minutes: 0.05 s of the gesture (the opening),
the level study at the DEFAULT tolerances and the levels' own rows against the paper
half face (the time-stepping and Newton error of the DEFAULT tolerances, the reference
face's against its TIGHT run in the default sweep, is under a tenth of the smallest error
measured here; docs/accuracy.md),
LOOSE runs, and full face, formulation "full" and stiffening off on the coarse face only;
no fine level, no reference face. Exits with status 1 unless the error falls as the
level rises (coarse > medium).

--list runs nothing: it prints the runs of the sweep (or of --only), each with its
reference, knobs and preset, and writes them to DIR/runs.csv.

Output in DIR (default out/accuracy_vs_time[_quick]): accuracy_vs_time.csv (a row per run),
records.json (each run's recorded outputs over time, by label), pareto.png (error against
time, log scales, the front of the generic-face runs drawn and the presets labelled); the
table, the fitted rate and the presets' figures are printed.
"""

import argparse
import json
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):                     # run as a script: the repository root
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from solver.sweep import Sweep  # noqa: E402
from benchmarks.table import report  # noqa: E402
from solver.face.terms.contact import PENALTY  # noqa: E402
from solver.face.anatomy.reference import reference_face_dir  # noqa: E402

REFERENCE_FACE = reference_face_dir()
LEVELS = ("coarse", "medium", "paper", "fine")
KNOBS = ("anatomy", "level", "rows", "half", "integrator", "substep_tol", "substep_rtol",
         "max_substep", "newton_rtol", "newton_utol", "lip_penalty", "formulation",
         "stiffening")
# the Scene defaults, written out so that every row of the table says what it ran
DEFAULT = dict(anatomy="generic", level="paper", rows=None, half=True,
               integrator="backward_euler", substep_tol=1e-3, substep_rtol=0.0,
               max_substep=5e-3, newton_rtol=1e-6, newton_utol=1e-5, lip_penalty=PENALTY,
               formulation="mean_dilatation", stiffening=True)
TIGHT = dict(substep_tol=2.5e-4, max_substep=2.5e-3, newton_rtol=1e-8)
LOOSE = dict(substep_tol=1e-2, max_substep=1e-2, newton_rtol=1e-4)
GESTURE_DURATION = 0.1     # s
STUDY_ROWS = 2             # brick rows per layer of the level study
QUICK_DURATION = 0.05      # s


def gesture(duration=GESTURE_DURATION, contact=True):
    """The benchmark scene, as a dict for solver.app.scene.parse_scene: the built-in scene
    `open_round` (solver/app/scenes/open_round.toml; the realtime model of the sweep is trained
    on it) over `duration` s."""
    import tomllib
    from solver.app.simulation import BUILTIN_DIR

    with open(BUILTIN_DIR / "open_round.toml", "rb") as fh:
        data = tomllib.load(fh)
    data["scene"]["duration"] = duration
    data["effects"] = {"lip_contact": contact, "teeth_contact": contact}
    return data


def knob(row, key):
    """A run's knob; DEFAULT's where a table of an earlier version has no such column."""
    return row.get(key, DEFAULT[key])


def with_rows(knobs):
    """knobs with rows written out: a generic face's rows None is its level's own."""
    from solver.face.anatomy.generic import LEVELS as MESHES

    if knobs["anatomy"] == "generic" and knobs.get("rows") is None:
        return {**knobs, "rows": MESHES[knobs["level"]][1]}
    return knobs


def spec(label, ref, **knobs):
    """A run: its label, the label of its reference run (None: it is one), every KNOB."""
    return with_rows({"label": label, "ref": ref, **DEFAULT, **knobs})


def sweep_specs(quick=False, reference_face=None):
    """The runs of the sweep (quick or default), the longest first (tasks start in order)."""
    if quick:       # level study at the DEFAULT tolerances, paper the reference
        levels, ref = LEVELS[:3], "paper"
        runs = [spec(lv, None if lv == "paper" else ref, level=lv) for lv in levels]
    else:           # level study at STUDY_ROWS, fine the reference
        levels, ref = LEVELS, "fine"
        runs = [spec("fine", None, level="fine", rows=STUDY_ROWS)]
        runs += [spec(f"{lv} {STUDY_ROWS} rows", ref, level=lv, rows=STUDY_ROWS)
                 for lv in levels[:-1]]
        runs += [spec(lv, ref, level=lv) for lv in levels[:-1]]
        runs += [spec("medium tight", ref, level="medium", **TIGHT)]
    runs += [spec(f"{lv} loose", ref, level=lv, **LOOSE) for lv in levels[:3]]
    if not quick:                   # the thickness at LOOSE: a cheaper balanced?
        runs.append(spec(f"medium {STUDY_ROWS} rows loose", ref, level="medium",
                         rows=STUDY_ROWS, **LOOSE))
    whole = "coarse" if quick else "medium"       # half against full face
    runs += [spec(f"{whole} full face", ref, level=whole, half=False),
             spec("coarse formulation full", ref, level="coarse", formulation="full"),
             spec(f"{whole} no stiffening", ref, level=whole, stiffening=False)]
    if not quick:
        runs.append(spec("medium formulation full", ref, level="medium", formulation="full"))
    runs += preset_specs(runs, ref)
    if not quick:
        runs += tolerance_specs(ref)
        runs += [scene_spec(ref)]
        runs.append(realtime_spec(ref))
    if not quick and reference_face is not None and (reference_face / "newface.node").is_file():
        face, rref = str(reference_face.resolve()), "reference face tight"
        runs += [spec(rref, None, anatomy=face, **TIGHT),
                 spec("reference face", rref, anatomy=face),
                 spec("reference face loose", rref, anatomy=face, **LOOSE),
                 spec("reference face full", rref, anatomy=face, half=False)]
    return sorted(runs, key=_cost_guess, reverse=True)


def select(specs, labels, available=()):
    """The specs named in labels and their reference runs (but those in `available`, run
    earlier); ValueError naming unknown ones."""
    by_label = {s["label"]: s for s in specs}
    unknown = [x for x in labels if x not in by_label]
    if unknown:
        raise ValueError(f"no run {unknown[0]!r}; runs: {', '.join(by_label)}")
    keep = set(labels) | {by_label[x]["ref"] for x in labels} - set(available)
    return [s for s in specs if s["label"] in keep]


def realtime_spec(ref):
    """The reduced-order fidelity `realtime` (solver.rom) on the gesture: its full-order
    knobs (solver.app.fidelity.REDUCED) and the model trained on the scene open_round."""
    from solver.app.fidelity import REDUCED

    return spec("realtime", ref, fidelity="realtime", **REDUCED["realtime"])


def realtime_model_missing(specs, duration):
    """Drop the realtime run from specs when no model of the gesture is trained (printing
    the training command); the specs left."""
    from solver.rom.store import ModelNotTrained, find_model
    from solver.app.scene import parse_scene
    from solver.app.fidelity import apply_fidelity

    if not any(s.get("fidelity") == "realtime" for s in specs):
        return specs
    try:
        find_model(apply_fidelity(parse_scene(gesture(duration)), "realtime"))
        return specs
    except ModelNotTrained:
        print("realtime: no trained model of the gesture (train it with `python "
              "benchmarks/rom_train.py --scene open_round`); its run is left out")
        return [s for s in specs if s.get("fidelity") != "realtime"]


def scene_spec(ref, scene="default"):
    """The built-in scene's own settings (its level, rows and [solver] section) on the
    gesture: where a run without a fidelity preset falls against the presets."""
    from solver.app.simulation import resolve_scene

    own = resolve_scene(scene)
    return spec(f"{scene} scene", ref, **{k: getattr(own, k) for k in KNOBS})


def tolerance_specs(ref):
    """The `balanced` and `fast` presets at tighter substep error tolerances than their own,
    and with backward Euler at the substep tolerance 5e-2 mm (the rest of each preset as it
    is): what the preset's integrator and substep tolerance cost in error and save in time
    (solver/app/fidelity.py, docs/accuracy.md)."""
    from solver.app.fidelity import PRESETS

    out = []
    for name, tols in (("balanced", (1e-2, 3e-2)), ("fast", (5e-2,))):
        knobs = with_rows({**DEFAULT, **PRESETS[name]})
        out += [spec(f"{name} at substep_tol {tol:g}", ref, **{**knobs, "substep_tol": tol})
                for tol in tols if tol < knobs["substep_tol"]]
        if knobs["integrator"] != "backward_euler":
            out.append(spec(f"{name} backward Euler", ref, **{
                **knobs, "integrator": "backward_euler", "substep_tol": 5e-2}))
    return out


def preset_specs(runs, ref):
    """Runs of the fidelity presets that no run in runs matches (their knobs, DEFAULT
    elsewhere); none where a preset asks for a level finer than the reference's."""
    from solver.app.fidelity import FIDELITIES, PRESETS

    out = []
    ref_level = next(r["level"] for r in runs if r["label"] == ref)
    for name in FIDELITIES:
        knobs = with_rows({**DEFAULT, **PRESETS[name]})
        if LEVELS.index(knobs["level"]) > LEVELS.index(ref_level):
            continue
        if not any(all(knob(r, k) == knobs[k] for k in KNOBS) for r in runs):
            out.append(spec(f"preset {name}", ref, **knobs))
    return out


def _cost_guess(s):
    """A rough relative cost of a run, to start the long ones first."""
    size = 12.0 if s["anatomy"] != "generic" else \
        {"coarse": 1, "medium": 2.5, "paper": 12, "fine": 75}[s["level"]] * s["rows"]
    return size * (1 if s["half"] else 2.5) * (1e-3 / s["substep_tol"]) ** 0.5


def run_specs(sweep, specs, duration, progress=True):
    """Run specs over `duration` s of the gesture on a solver.sweep.Sweep; the sweep's
    results (see solver.sweep.run_task), in the order of specs."""
    tasks = [{k: v for k, v in s.items() if k != "ref"} | {"duration": duration}
             for s in specs]
    return sweep.run(tasks, gesture(duration), progress)


def output_errors(rows, ref_rows):
    """(aperture, protrusion): the largest |run - reference| over the record times (mm)."""
    if len(rows) != len(ref_rows) or any(abs(a["time"] - b["time"]) > 1e-9
                                         for a, b in zip(rows, ref_rows)):
        raise ValueError("the runs do not share their record times")
    return tuple(max(abs(a[k] - b[k]) for a, b in zip(rows, ref_rows))
                 for k in ("lip_aperture", "lip_protrusion"))


def evaluate(specs, results, earlier=None):
    """Table rows (dicts) from run specs and their sweep results (same order); earlier:
    {label: recorded rows} of runs not run here (--merge) that may be references."""
    by_label = {label: {"error": "", "rows": rows} for label, rows in (earlier or {}).items()}
    by_label.update({s["label"]: r for s, r in zip(specs, results)})
    table = []
    for s, r in zip(specs, results):
        row = {k: s[k] for k in ("label", *KNOBS)}
        row["fidelity"] = s.get("fidelity", "")
        if s["anatomy"] != "generic":
            row.update(anatomy="reference", level="-")
        row["reference"] = s["ref"] or "-"
        row["error"] = r["error"]
        if not r["error"]:
            row.update({k: r[k] for k in ("ndof", "wall_s", "cpu_s", "rtf", "peak_mb")})
            row["h_mm"] = (r["volume_mm3"] / r["bricks"]) ** (1.0 / 3.0)
            ref = by_label[s["ref"]] if s["ref"] else None
            if ref is not None and ref["error"]:
                row["error"] = f"its reference failed: {ref['error']}"
            elif ref is not None:
                ea, ep = output_errors(r["rows"], ref["rows"])
                row.update(err_aperture_mm=ea, err_protrusion_mm=ep, err_mm=max(ea, ep))
        table.append(row)
    return table


def pareto_mask(cost, err):
    """(n,) bool: the points that no other point beats in both cost and error."""
    cost, err = np.asarray(cost, float), np.asarray(err, float)
    return np.array([not np.any((cost <= c) & (err <= e) & ((cost < c) | (err < e)))
                     for c, e in zip(cost, err)])


def mark_front(table, cost="wall_s"):
    """Set row["pareto"] on the generic-face rows with an error; return those rows."""
    rows = [r for r in table if r["anatomy"] == "generic" and "err_mm" in r]
    for r, on in zip(rows, pareto_mask([r[cost] for r in rows], [r["err_mm"] for r in rows])):
        r["pareto"] = bool(on)
    return rows


def mark_presets(table):
    """Set row["preset"] on the generic-face rows whose knobs are a fidelity preset's."""
    from solver.app.fidelity import FIDELITIES, PRESETS

    for r in table:                   # the current presets (also on a --replot of a table)
        r["preset"] = r.get("fidelity", "")             # "realtime": the reduced model
    for name in FIDELITIES:
        knobs = with_rows({**DEFAULT, **PRESETS[name]})
        for r in table:
            if r["anatomy"] == "generic" and not r.get("fidelity") and \
                    all(knob(r, k) == knobs[k] for k in KNOBS):
                r["preset"] = name


def fit_rate(h, err):
    """(p, c) of the least-squares fit log err = log c + p log h."""
    p, logc = np.polyfit(np.log(h), np.log(err), 1)
    return float(p), float(math.exp(logc))


def level_study(table):
    """The rows of the level study: the generic-face runs that differ from the reference
    run of the generic face in their level alone, coarse first; the fitted rates {error
    column: p}; whether err_mm falls strictly as the level rises."""
    ref = next((r for r in table if r["anatomy"] == "generic" and r["reference"] == "-"),
               None)
    if ref is None:
        return [], {}, False
    same = [k for k in KNOBS if k != "level"]
    rows = sorted((r for r in table if r["reference"] == ref["label"] and "err_mm" in r
                   and all(knob(r, k) == knob(ref, k) for k in same)),
                  key=lambda r: LEVELS.index(r["level"]))
    rates = {}
    if len(rows) >= 2:
        for k in ("err_aperture_mm", "err_protrusion_mm", "err_mm"):
            if all(r[k] > 0 for r in rows):
                rates[k] = fit_rate([r["h_mm"] for r in rows], [r[k] for r in rows])[0]
    falls = len(rows) >= 2 and all(a["err_mm"] > b["err_mm"] for a, b in zip(rows, rows[1:]))
    return rows, rates, falls


MARKERS = {"reduced order": "*", "tight": "D", "default": "o", "loose": "v", "one loose knob": "P",
           "full face": "s", "formulation full": "X", "no stiffening": "^"}
COLOURS = {"coarse": "tab:blue", "medium": "tab:orange", "paper": "tab:green",
           "fine": "tab:red", "-": "tab:purple"}


def family(r):
    """What a run changes: a key of MARKERS."""
    if r.get("fidelity") == "realtime":
        return "reduced order"
    if not r["half"]:
        return "full face"
    if r["formulation"] != DEFAULT["formulation"]:
        return "formulation full"
    if not r["stiffening"]:
        return "no stiffening"
    for name, tol in (("tight", TIGHT), ("loose", LOOSE),
                      ("default", {k: DEFAULT[k] for k in TIGHT})):
        if all(r[k] == v for k, v in tol.items()):
            return name
    return "one loose knob"


def plot(table, path, title, cost="wall_s"):
    """Error against cost, log scales: colour the level (purple: the reference face),
    marker what the run changes; the front drawn and labelled, the presets named, the
    reference runs (error 0) as dashed lines."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in table if r.get("err_mm", 0) > 0]
    fig, ax = plt.subplots(figsize=(9, 6))
    for r in ok:
        ax.scatter(r[cost], r["err_mm"], color=COLOURS[r["level"]], s=45, zorder=3,
                   marker=MARKERS[family(r)], edgecolor="k" if r.get("pareto") else "none")
        if r.get("pareto") or r["anatomy"] != "generic":
            ax.annotate(r["label"], (r[cost], r["err_mm"]), fontsize=7, xytext=(5, 3),
                        textcoords="offset points")
        if r.get("preset"):
            ax.annotate(r["preset"].upper(), (r[cost], r["err_mm"]), fontsize=10,
                        weight="bold", xytext=(-12, -16), textcoords="offset points")
    front = sorted((r for r in ok if r.get("pareto")), key=lambda r: r[cost])
    ax.step([r[cost] for r in front], [r["err_mm"] for r in front], where="post",
            color="k", lw=1.2, label="Pareto front (generic face)")
    for r in table:                                # reference runs: error 0 by definition
        if r["reference"] == "-" and not r["error"]:
            ax.axvline(r[cost], color=COLOURS[r["level"]], ls="--", lw=1)
            ax.annotate(f"{r['label']} (reference)", (r[cost], 0.02), rotation=90,
                        xycoords=("data", "axes fraction"), fontsize=7, xytext=(-9, 0),
                        textcoords="offset points")
    for lv in (*LEVELS, "-"):
        if any(r["level"] == lv for r in ok):
            ax.scatter([], [], color=COLOURS[lv], marker="o",
                       label=lv if lv != "-" else "reference face (against itself)")
    for name, marker in MARKERS.items():
        if any(family(r) == name for r in ok):
            ax.scatter([], [], color="grey", marker=marker, label=name)
    ax.set(xscale="log", yscale="log", title=title,
           xlabel=("wall" if cost == "wall_s" else "CPU") + " time of the run (s, one core)",
           ylabel="max error in lip aperture or protrusion (mm)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


COLUMNS = ["label", "fidelity", "level", "rows", "half", "integrator", "substep_tol",
           "substep_rtol", "max_substep",
           "newton_rtol", "newton_utol", "lip_penalty",
           "formulation", "stiffening", "ndof", "h_mm", "wall_s", "cpu_s", "rtf", "peak_mb",
           "err_aperture_mm", "err_protrusion_mm", "err_mm", "pareto", "preset",
           "reference", "anatomy", "error"]


def read_table(path):
    """The table of an earlier run from its accuracy_vs_time.csv (numbers and flags typed,
    empty cells left out)."""
    import csv

    table = []
    with open(path, newline="") as fh:
        for raw in csv.DictReader(fh):
            row = {}
            for k, v in raw.items():
                if v == "":
                    continue
                if k in ("half", "stiffening", "pareto"):
                    v = v == "True"
                elif k in ("ndof", "rows"):
                    v = int(float(v))
                elif k not in ("label", "fidelity", "level", "formulation", "preset",
                               "reference", "anatomy", "error", "integrator"):
                    v = float(v)
                row[k] = v
            row.setdefault("error", "")
            table.append(row)
    return table


def summary(table, out, title, cost="wall_s", quick=False):
    """Mark the front and the presets, print and save the table, the plot, the level
    study and the presets' figures; whether the error falls as the level rises."""
    mark_front(table, cost)
    mark_presets(table)
    report(table, COLUMNS, out / "accuracy_vs_time.csv")
    plot(table, out / "pareto.png", title, cost)
    rows, rates, falls = level_study(table)
    print(f"\nlevel study (against {rows[0]['reference'] if rows else '-'}): "
          + ", ".join(f"{r['level']} h {r['h_mm']:.2f} mm err {r['err_mm']:.3g} mm"
                      for r in rows))
    print("fitted rate p in err ~ h^p: "
          + (", ".join(f"{k} {p:.2f}" for k, p in rates.items()) or "too few levels"))
    print(f"error falls as the level rises: {'yes' if falls else 'NO'}")
    for r in table:
        if r.get("preset") and not r["error"]:
            error = (f"error aperture {r['err_aperture_mm']:.3g} mm, protrusion "
                     f"{r['err_protrusion_mm']:.3g} mm" if "err_mm" in r else
                     "the reference run: error not measured")
            print(f"preset {r['preset']}: '{r['label']}', {error}, real-time factor "
                  f"{r['rtf']:.0f} (wall), {r['rtf'] * r['cpu_s'] / r['wall_s']:.0f} (CPU)"
                  + ("" if r.get("pareto", True) else ", NOT on the Pareto front"))
    failed = [r["label"] for r in table if r["error"]]
    if failed:
        print(f"failed runs: {failed}")
    print(f"wrote {out / 'accuracy_vs_time.csv'} and {out / 'pareto.png'}")
    return falls


def markdown(table, path, cost, made, argv):
    """The sweep's figures as a markdown page at path: the command, commit, date and wall
    time, then a row per run (cost, errors against its reference, front, preset) and the
    level study; docs/accuracy.md includes it."""
    from solver.app.provenance import command, stamp

    def num(v, fmt="{:.3g}"):
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)
    rows, rates, _ = level_study(table)
    lines = [f"Made by `{command('benchmarks/accuracy_vs_time.py', argv)}` {stamp()}, "
             f"{made}. Cost: {cost} (s) of the gesture's run; errors: "
             "the largest difference over time from the row's reference run (mm).", "",
             "run | reference | rows | dof | cpu_s | wall_s | rtf | err aperture | "
             "err protrusion | front | preset",
             "--- | --- | --- | --- | --- | --- | --- | --- | --- | --- | ---"]
    for r in sorted(table, key=lambda r: -r.get(cost, 0.0)):
        if r.get("error"):
            lines.append(f"{r['label']} | {r.get('reference', '-')} | - | - | - | - | - | "
                         f"FAILED: {r['error']} | | |")
            continue
        lines.append(" | ".join([
            r["label"], r.get("reference", "-") or "-", num(r.get("rows"), "{}"),
            num(r.get("ndof"), "{}"), num(r.get("cpu_s")), num(r.get("wall_s")),
            num(r.get("rtf"), "{:.0f}"), num(r.get("err_aperture_mm")),
            num(r.get("err_protrusion_mm")), "yes" if r.get("pareto") else "",
            r.get("preset", "") or ""]))
    if rows:
        lines += ["", f"Level study (against {rows[0]['reference']}): " + ", ".join(
            f"{r['level']} h {r['h_mm']:.2f} mm, error {r['err_mm']:.3g} mm" for r in rows)
            + "; fitted rate p in err ~ h^p: "
            + (", ".join(f"{k} {p:.2f}" for k, p in rates.items()) or "too few levels") + "."]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")


def write_doc(table, args, out, cost, made, argv):
    """markdown() at args.doc, and the plot of out copied to args.img (each if given)."""
    if args.doc:
        markdown(table, args.doc, cost, made, sys.argv[1:] if argv is None else argv)
    if args.img:
        args.img.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(out / "pareto.png", args.img)


def list_specs(specs, path):
    """Print the runs (label, reference, preset, KNOBS) and save them as a CSV at path."""
    table = [{"label": s["label"], "reference": s["ref"] or "-",
              "fidelity": s.get("fidelity", ""), **{k: s[k] for k in KNOBS}} for s in specs]
    mark_presets(table)
    report(table, ["label", "reference", "fidelity", "preset", *KNOBS], path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help=f"coarse and medium against paper over {QUICK_DURATION} s")
    ap.add_argument("--duration", type=float,
                    help=f"s of the gesture (default {GESTURE_DURATION}, quick "
                         f"{QUICK_DURATION})")
    ap.add_argument("--out", type=Path, help="output folder")
    ap.add_argument("--scheduler", help="address of a running dask scheduler "
                                        "(default: a LocalCluster on this machine)")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes")
    ap.add_argument("--only", help="comma-separated run labels: run these and their "
                                   "reference runs alone")
    ap.add_argument("--cost", choices=("wall", "cpu"), default="wall",
                    help="time of the front and plot: wall_s, or cpu_s (the worker's CPU "
                         "time, the wall time on an idle core)")
    ap.add_argument("--merge", type=Path, metavar="DIR",
                    help="with --only: the other runs' rows, and the references of the runs "
                         "named (not run again), from the earlier sweep in DIR "
                         "(accuracy_vs_time.csv, records.json); all in --out")
    ap.add_argument("--replot", type=Path, metavar="DIR",
                    help="no runs: the table, front and plot again from DIR's "
                         "accuracy_vs_time.csv (for instance with another --cost)")
    ap.add_argument("--doc", type=Path, metavar="FILE",
                    help="also write the table as markdown there (docs/generated/"
                         "accuracy_sweep.md, which docs/accuracy.md includes)")
    ap.add_argument("--img", type=Path, metavar="FILE",
                    help="also copy the plot there (docs/img/pareto.png)")
    ap.add_argument("--list", action="store_true",
                    help="no runs: the runs of the sweep (with --only: those and their "
                         "references), their references, knobs and presets, printed and "
                         "written to OUT/runs.csv")
    args = ap.parse_args(argv)
    cost = f"{args.cost}_s"
    t_start = time.perf_counter()
    if args.replot:
        table = read_table(args.replot / "accuracy_vs_time.csv")
        duration = next(r["wall_s"] / r["rtf"] for r in table if "rtf" in r)
        falls = summary(table, args.replot, f"gesture over {duration:.3g} s: error against "
                        f"{args.cost} time" + (" (--quick)" if args.quick else ""), cost)
        if args.doc or args.img:
            write_doc(table, args, args.replot, cost, "the figures of the sweep in "
                      f"{args.replot}, replotted", argv)
        return 0 if falls or not args.quick else 1
    duration = args.duration or (QUICK_DURATION if args.quick else GESTURE_DURATION)
    out = args.out or Path("out") / ("accuracy_vs_time" + ("_quick" if args.quick else ""))
    out.mkdir(parents=True, exist_ok=True)
    if not args.quick and not (REFERENCE_FACE / "newface.node").is_file():
        print(f"reference face not found in {REFERENCE_FACE}: its runs are skipped")
    specs = sweep_specs(args.quick, REFERENCE_FACE)
    earlier_table, earlier = [], {}
    if args.merge:
        if not args.only:
            ap.error("--merge needs --only (the runs to add or run again)")
        earlier_table = read_table(args.merge / "accuracy_vs_time.csv")
        with open(args.merge / "records.json") as fh:
            earlier = {k: v for k, v in json.load(fh).items() if v}
    if args.only:
        try:
            specs = select(specs, [x.strip() for x in args.only.split(",")],
                           set(earlier))
        except ValueError as exc:
            ap.error(str(exc))
    if args.list:
        list_specs(specs, out / "runs.csv")
        return 0
    specs = realtime_model_missing(specs, duration)
    with Sweep(args.scheduler, n_workers=args.workers) as sweep:
        print(f"{len(specs)} runs of {duration} s of the gesture on "
              f"{len(sweep.workers)} workers")
        results = run_specs(sweep, specs, duration)
    run_here = {s["label"] for s in specs}
    records = {k: v for k, v in earlier.items() if k not in run_here}
    records.update({r["label"]: r.get("rows", []) for r in results})
    with open(out / "records.json", "w") as fh:      # every run's outputs over time
        json.dump(records, fh)
    table = [r for r in earlier_table if r["label"] not in run_here]
    if table:
        print(f"{len(table)} rows from {args.merge}, {len(specs)} run here")
    table += evaluate(specs, results, earlier)
    falls = summary(table, out, f"gesture over {duration} s: error "
                    f"against {args.cost} time" + (" (--quick)" if args.quick else ""), cost)
    if args.doc or args.img:
        write_doc(table, args, out, cost, f"{(time.perf_counter() - t_start) / 60:.1f} "
                  "min in all", argv)
    return 0 if falls or not args.quick else 1


if __name__ == "__main__":
    sys.exit(main())
