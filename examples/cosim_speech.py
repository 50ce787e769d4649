"""Build FaceFMU and the LipMotorControl FMU, connect them, and co-simulate a sequence of
speech lip targets through fmpy; exit 1 if a target is missed.

    python examples/cosim_speech.py [--step 0.005] [--out out/cosim] [--targets FILE]
                                    [--scene default] [--fidelity fast] [--level coarse]

The controller's ten activations and jaw opening drive the face; the face's lip aperture,
protrusion and width feed back to the controller. A target is met when, at the end of its window, the
aperture and protrusion errors are each within 0.3 mm, and the width error within 0.5 mm
where the width is targeted. Prints the tracking table, the wall time and the real-time
factor, and writes a CSV and a PNG of targets, outputs and activations.

The face runs at the `fast` fidelity preset (solver/app/fidelity.py, docs/presets.md), on
which the controller's map was identified (examples/motor_control/identify.py).
--fidelity realtime runs the face's reduced-order model (the one that ships with the
project for the default scene), then the same controller with the full-order model of the
mesh it was trained on (fidelity "", level coarse), and prints the largest difference
between the two runs' outputs; --level applies to fidelity "" only (a fidelity sets the
mesh).
"""

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONTROL = Path(__file__).resolve().parent / "motor_control"
TOLERANCE = {"lip_aperture": 0.3, "lip_protrusion": 0.3, "lip_width": 0.5}     # mm
OUTPUTS = ("lip_aperture", "lip_protrusion", "lip_width")
TARGETS = {"lip_aperture": "target_aperture", "lip_protrusion": "target_protrusion",
           "lip_width": "target_width"}
MUSCLES = ("LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM")


def build_fmus(dest):
    """Build both FMUs in child processes: building imports the slave scripts, and a
    solver package imported here would shadow the FMU's own copy at run time."""
    dest = Path(dest).resolve()              # the controller's build runs in CONTROL
    subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", str(dest)],
                   check=True, stdout=subprocess.DEVNULL)
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f",
                    str(CONTROL / "lip_motor_control.py"), "-d", str(dest),
                    "--no-external-tool", str(CONTROL / "lipmc_inverse.py"),
                    str(CONTROL / "inverse_model.json")],
                   check=True, stdout=subprocess.DEVNULL, cwd=CONTROL)
    control = dest / "LipMotorControl.fmu"
    # pythonfmu's wrapper, corrected as FaceFMU's is (docs/dev-notes/exit-crash.md)
    subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--fix-wrapper", str(control)],
                   check=True, stdout=subprocess.DEVNULL)
    return dest / "FaceFMU.fmu", control


def instantiate(path, name, start_values=None):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    md = read_model_description(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu.enterInitializationMode()
    for key, value in (start_values or {}).items():
        if isinstance(value, str):
            fmu.setString([vr[key]], [value])
        elif isinstance(value, bool):
            fmu.setBoolean([vr[key]], [value])
        else:
            fmu.setReal([vr[key]], [value])
    fmu.exitInitializationMode()
    return fmu, vr


def cosimulate(face_fmu, control_fmu, stop, step, face_params=None, control_params=None):
    """Step both FMUs together, as a fixed-step master does (libcosim, SSP): each step both
    FMUs take the other's outputs at t as their inputs, then step to t + step. Returns rows:
    the target active over [t, t + step], the activations applied over it, and the face's
    outputs at t + step."""
    face, fv = instantiate(face_fmu, "face", face_params)
    ctrl, cv = instantiate(control_fmu, "control", control_params)
    rows, t = [], 0.0
    jaw = "jaw_opening" in cv and "jaw_opening" in fv          # both FMUs have the jaw
    for _ in range(int(round(stop / step))):
        y = face.getReal([fv[o] for o in OUTPUTS])
        acts = ctrl.getReal([cv[m] for m in MUSCLES])
        opening = ctrl.getReal([cv["jaw_opening"]])[0] if jaw else 0.0
        targets = ctrl.getReal([cv[TARGETS[o]] for o in OUTPUTS])
        phoneme = ctrl.getString([cv["phoneme"]])[0]
        ctrl.setReal([cv[o] for o in OUTPUTS], y)
        face.setReal([fv[m] for m in MUSCLES], acts)
        if jaw:
            face.setReal([fv["jaw_opening"]], [opening])
        ctrl.doStep(t, step)
        face.doStep(t, step)
        t += step
        y = face.getReal([fv[o] for o in OUTPUTS])
        incisors = face.getReal([fv["incisor_opening"]])[0] if jaw else 0.0
        rows.append({"time": t, "phoneme": phoneme.decode() if isinstance(phoneme, bytes)
                     else phoneme, **{TARGETS[o]: v for o, v in zip(OUTPUTS, targets)},
                     **dict(zip(OUTPUTS, y)), **dict(zip(MUSCLES, acts)),
                     "jaw_opening": opening, "incisor_opening": incisors})
    for f in (face, ctrl):
        f.terminate()
        f.freeInstance()
    return rows


def load_targets(path=None):
    """The target list of a JSON file (a list, or inverse_model.json's "targets")."""
    data = json.loads(Path(path or CONTROL / "inverse_model.json").read_text())
    return data["targets"] if isinstance(data, dict) else data


def tracking(rows, targets):
    """Per target, at the end of its window: [(target dict, {output: (target, achieved,
    error, tolerance, met)})] for the targeted outputs."""
    out, end = [], 0.0
    for tg in targets:
        end += tg["duration"]
        row = min(rows, key=lambda r: abs(r["time"] - end))
        checks = {}
        for o in OUTPUTS:
            if o in tg["targeted"]:
                err = row[o] - tg[o]
                checks[o] = (tg[o], row[o], err, TOLERANCE[o], abs(err) <= TOLERANCE[o])
        out.append((tg, row["time"], checks))
    return out


def table(results):
    lines = [f"{'target':8s}{'window end':12s}{'jaw deg':>8s}  {'output':16s}{'target':>8s}"
             f"{'achieved':>10s}{'error':>8s}{'tol':>6s}  result"]
    for tg, t, checks in results:
        for k, (o, (target, got, err, tol, met)) in enumerate(checks.items()):
            ph, end, jaw = (f"/{tg['phoneme']}/", f"{t:.3f} s",
                            f"{tg.get('jaw_opening', 0.0):.1f}") if k == 0 else ("", "", "")
            lines.append(f"{ph:8s}{end:12s}{jaw:>8s}  {o:16s}{target:8.2f}{got:10.2f}"
                         f"{err:+8.2f}{tol:6.1f}  {'met' if met else 'MISSED'}")
    return "\n".join(lines)


def report(rows, targets, wall, csv_path):
    """Print the tracking table and the wall time, write the rows to csv_path; returns
    the number of targets missed."""
    results = tracking(rows, targets)
    print(table(results))
    stop = sum(tg["duration"] for tg in targets)
    print(f"co-simulation: {wall:.1f} s of wall time for {stop:.2f} s of speech "
          f"(real-time factor {wall / stop:.1f})")
    with open(csv_path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return sum(not all(c[4] for c in checks.values()) for _, _, checks in results)


def compare_full(rows, face_fmu, control_fmu, stop, step, face, control):
    """Run the same controller with the scene's full-order model on the mesh the reduced
    one was trained on (fidelity "", level coarse) and print the largest difference of
    each output."""
    face.update(fidelity="", level="coarse")
    t0 = time.perf_counter()
    full = cosimulate(face_fmu, control_fmu, stop, step, face, control)
    wall = time.perf_counter() - t0
    diff = {o: max(abs(a[o] - b[o]) for a, b in zip(rows, full)) for o in OUTPUTS}
    print(f"full-order run of the same controller (level 'coarse'): {wall:.1f} s of "
          f"wall time (real-time factor {wall / stop:.1f}); largest difference of the "
          "realtime run from it: " + ", ".join(f"{o.split('_')[1]} {d:.3f} mm"
                                              for o, d in diff.items()))
    return diff


def plot(rows, targets, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = [r["time"] for r in rows]
    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    for a, o in zip(ax, OUTPUTS):
        a.plot(t, [r[o] for r in rows], color="C0", label=o.replace("_", " "))
        a.plot(t, [r[TARGETS[o]] for r in rows], "--", color="C1", label="target")
        a.set_ylabel(f"{o.split('_')[1]} (mm)")
    ax[0].plot(t, [r["incisor_opening"] for r in rows], ":", color="0.4",
               label="incisor opening (jaw)")
    for m in MUSCLES:
        if max(r[m] for r in rows) > 0.01:
            ax[3].plot(t, [r[m] for r in rows], label=m)
    ax[3].set_ylabel("activation")
    ax[3].set_xlabel("time (s)")
    end = 0.0
    for tg in targets:
        for a in ax:
            a.axvline(end, color="0.8", lw=0.8)
        ax[0].annotate(f"/{tg['phoneme']}/", (end + 0.005, 1.0),
                       xycoords=("data", "axes fraction"), va="top")
        end += tg["duration"]
    for a in ax:
        a.legend(loc="upper right", fontsize=8, ncol=4)
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step", type=float, default=0.005, help="communication step (s)")
    ap.add_argument("--out", default=str(ROOT / "out" / "cosim"))
    ap.add_argument("--targets", help="JSON list of targets (default: the identified ones "
                                      "in examples/motor_control/inverse_model.json)")
    ap.add_argument("--scene", default="default", help="FaceFMU's scene parameter")
    ap.add_argument("--level", default="coarse", help="FaceFMU's level parameter")
    ap.add_argument("--fidelity", default="fast", help="FaceFMU's fidelity parameter "
                    "(\"\": the scene's own settings at --level)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    targets = load_targets(args.targets)
    stop = sum(tg["duration"] for tg in targets)
    t0 = time.perf_counter()
    face_fmu, control_fmu = build_fmus(out)
    print(f"built {face_fmu.name} and {control_fmu.name} in {time.perf_counter() - t0:.1f} s")
    # a fresh machine compiles the solver's kernels first, on all cores (solver/app/warm.py)
    subprocess.run([sys.executable, "-m", "solver.app.warm", "--quiet"], cwd=ROOT)
    face = {"scene": args.scene, "fidelity": args.fidelity}
    if not args.fidelity:
        face["level"] = args.level
    control = {"targets_file": str(Path(args.targets).resolve())} if args.targets else {}
    print(f"co-simulating {stop:.2f} s of speech at {args.step * 1e3:g} ms steps: FaceFMU "
          f"scene {args.scene!r}, " + (f"fidelity {args.fidelity!r}" if args.fidelity else
                                        f"level {args.level!r}, the scene's fidelity"))
    t0 = time.perf_counter()
    rows = cosimulate(face_fmu, control_fmu, stop, args.step, face, control)
    missed = report(rows, targets, time.perf_counter() - t0, out / "cosim.csv")
    plot(rows, targets, out / "cosim.png")
    print(f"wrote {out / 'cosim.csv'} and {out / 'cosim.png'}")
    if args.fidelity == "realtime":
        compare_full(rows, face_fmu, control_fmu, stop, args.step, dict(face), control)
    if missed:
        print(f"FAILED: {missed} of {len(targets)} targets missed")
        return 1
    print(f"all {len(targets)} targets met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
