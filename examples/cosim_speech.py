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
import subprocess
import sys
import time
from pathlib import Path

from facefmu.cosim import Master, Record, read_system
from facefmu.speech import (OUTPUTS, TARGETS, duration, missed, records, table,  # noqa: F401
                            tracking)
from facefmu.speech import load_targets as _load_targets

ROOT = Path(__file__).resolve().parents[1]
CONTROL = Path(__file__).resolve().parent / "motor_control"
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


def load_targets(path=None):
    """The target list of a JSON file (default: the identified ones)."""
    return _load_targets(path or CONTROL / "inverse_model.json")


def speech_system(face_fmu, control_fmu, step):
    """The two-FMU system of examples/motor_control/OspSystemStructure.xml with these FMUs
    and communication step."""
    system = read_system(CONTROL / "OspSystemStructure.xml",
                         fmus={"face": face_fmu, "control": control_fmu})
    system.step = step
    return system


def _echo(simulator, status, message):
    """The FMUs' log as it comes: FaceFMU's compile notice, warnings and worse."""
    if status != "ok" or "compil" in message:
        print(f"[{simulator} {status}] {message}", flush=True)


def cosimulate(face_fmu, control_fmu, stop, step, face_params=None, control_params=None):
    """The speech co-simulation (facefmu.cosim's master, records of facefmu.speech): a
    facefmu.cosim.Result whose rows hold, per step, the target active over [t, t + step],
    the activations applied over it, and the face's outputs at t + step."""
    system = speech_system(face_fmu, control_fmu, step)
    recs = records(system)
    if (face_params or {}).get("fidelity") == "realtime":     # the full model's share
        recs.append(Record("rom_full_time", "face", "rom_full_time"))
    with Master(system, recs, echo=_echo) as master:
        return master.run(stop, {"face": face_params or {}, "control": control_params or {}})


def report(rows, targets, wall, csv_path):
    """Print the tracking table and the wall time, write the rows to csv_path; returns
    the number of targets missed."""
    results = tracking(rows, targets)
    print(table(results))
    stop = duration(targets)
    print(f"co-simulation: {wall:.1f} s of wall time for {stop:.2f} s of speech "
          f"(real-time factor {wall / stop:.1f})")
    with open(csv_path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return missed(results)


def compare_full(rows, face_fmu, control_fmu, stop, step, face, control):
    """Run the same controller with the scene's full-order model on the mesh the reduced
    one was trained on (fidelity "", level coarse) and print the largest difference of
    each output."""
    face.update(fidelity="", level="coarse")
    result = cosimulate(face_fmu, control_fmu, stop, step, face, control)
    if not result.ok:
        print(f"full-order run failed: {result.reason}")
        return None
    full, wall = result.rows, result.wall
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
    # a fresh machine compiles the solver's kernels on all cores (solver/app/warm.py) while
    # the FMUs are built; where they are compiled already this returns at once
    warm = subprocess.Popen([sys.executable, "-m", "solver.app.warm", "--quiet"], cwd=ROOT)
    try:
        face_fmu, control_fmu = build_fmus(out)
    except BaseException:
        warm.kill()
        raise
    print(f"built {face_fmu.name} and {control_fmu.name} in {time.perf_counter() - t0:.1f} s",
          flush=True)
    warm.wait()
    face = {"scene": args.scene, "fidelity": args.fidelity}
    if not args.fidelity:
        face["level"] = args.level
    control = {"targets_file": str(Path(args.targets).resolve())} if args.targets else {}
    print(f"co-simulating {stop:.2f} s of speech at {args.step * 1e3:g} ms steps: FaceFMU "
          f"scene {args.scene!r}, " + (f"fidelity {args.fidelity!r}" if args.fidelity else
                                        f"level {args.level!r}, the scene's fidelity"))
    result = cosimulate(face_fmu, control_fmu, stop, args.step, face, control)
    if not result.ok:
        print(f"FAILED: the co-simulation stopped: {result.reason}")
        return 1
    rows = result.rows
    n_missed = report(rows, targets, result.wall, out / "cosim.csv")
    plot(rows, targets, out / "cosim.png")
    print(f"wrote {out / 'cosim.csv'} and {out / 'cosim.png'}")
    if args.fidelity == "realtime":
        print(f"the full model ran {100 * rows[-1]['rom_full_time'] / stop:.0f} % of the "
              "simulated time (FaceFMU's rom_full_time: handovers from the reduced model)")
        compare_full(rows, face_fmu, control_fmu, stop, args.step, dict(face), control)
    if n_missed:
        print(f"FAILED: {n_missed} of {len(targets)} targets missed")
        return 1
    print(f"all {len(targets)} targets met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
