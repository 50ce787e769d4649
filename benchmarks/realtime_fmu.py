"""The realtime (reduced-order) fidelity through the FMU: wall time, real-time factor and
error against the full-order model on a lip gesture.

    python benchmarks/realtime_fmu.py [--fmu FILE.fmu] [--model FILE.npz] [--step 0.005]
                                      [--gesture oop_ris] [--repeat 5] [--no-full]
                                      [--no-balanced] [--md FILE]

1. The FMU: --fmu, or built here (build_fmu.py) with the model that ships for the
   `speech` scene (solver/rom/models; all ten muscles, lip and teeth contact, the jaw),
   or --model packed in.
2. Co-simulation through fmpy in a fresh process (FMU2Slave, scene "speech", fidelity
   "realtime"): the gesture's activations set before every doStep of `--step` seconds
   (5 ms, the main job's), outputs read after each; the FMU's rom_fallbacks and
   rom_full_time after the run: the full model's share of the simulated time. Timed:
   the stepping loop (setReal, doStep, getReal), not instantiation and initialization
   (reported apart). Real-time factor = wall time /
   simulated time; `--repeat` runs (fresh instances), the best and all reported.
3. The same reduced model in this process (open_simulation(..., fidelity="realtime"),
   same steps): its wall time, and its outputs against the FMU's.
4. The full-order model of the scene at the realtime knobs (coarse generic half face,
   loose tolerances; 5 ms caller steps, as solver.rom.accuracy) on the same gesture: the
   largest difference in lip aperture and protrusion over its 5 ms records (--no-full
   leaves it out): the reduced model's own error.
5. Beside it, the same FMU at fidelity "balanced" (the full-order model of the finer
   face, solver.app.fidelity), one run at the same steps: its real-time factor and the
   realtime runs' largest difference from it in lip aperture and protrusion, what a user
   gives up for the speed (--no-balanced leaves it out).

The gesture (solver.rom.accuracy.GESTURES, --gesture; jaw inputs go to the FMU's jaw):
oop_ris, 0.3 s, OOP 0 -> 1 and RIS 0 -> 0.5 over 0-0.15 s, held. Prints the machine load
(os.getloadavg) before and after; --md writes the gesture's markdown table row into FILE
(replacing that gesture's earlier row) with the command and the commit.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

FMPY_RUN = r"""
import json, sys, time
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
path, out, step, duration, repeat = sys.argv[1], sys.argv[2], float(sys.argv[3]), \
    float(sys.argv[4]), int(sys.argv[5])
sched, fidelity = json.loads(sys.argv[6]), sys.argv[7]
md = read_model_description(path)
vr = {v.name: v.valueReference for v in md.modelVariables}
unzip = extract(path)
names = ["lip_aperture", "lip_protrusion", "contact_force"]
muscles = sorted(sched)
n = int(round(duration / step))
res = {"runs": []}
messages = []
def logger(component, instance, status, category, message):
    messages.append(message.decode())
def value(m, t):
    times, values = sched[m]
    if t <= times[0]:
        return values[0]
    for (t0, t1), (v0, v1) in zip(zip(times, times[1:]), zip(values, values[1:])):
        if t <= t1:
            return v0 + (v1 - v0) * (t - t0) / (t1 - t0)
    return values[-1]
for k in range(repeat):
    t0 = time.perf_counter()
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip, instanceName=f"rt{k}",
                    modelIdentifier=md.coSimulation.modelIdentifier)
    fmu.instantiate(loggingOn=True, callbacks=None)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setString([vr["scene"], vr["fidelity"]], ["speech", fidelity])
    fmu.exitInitializationMode()
    init = time.perf_counter() - t0
    rows = [[0.0] + list(fmu.getReal([vr[x] for x in names]))]
    refs = [vr[m] for m in muscles]
    out_refs = [vr[x] for x in names]
    w0, c0 = time.perf_counter(), time.process_time()
    for i in range(n):
        t = i * step
        fmu.setReal(refs, [value(m, t + step) for m in muscles])
        fmu.doStep(t, step)
        rows.append([t + step] + list(fmu.getReal(out_refs)))
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    fallbacks = fmu.getInteger([vr["rom_fallbacks"]])[0]
    full_time = fmu.getReal([vr["rom_full_time"]])[0]
    fmu.terminate()
    fmu.freeInstance()
    res["runs"].append({"init_s": init, "wall_s": wall, "cpu_s": cpu, "rows": rows,
                        "fallbacks": fallbacks, "full_time": full_time})
res["messages"] = messages[-5:]
json.dump(res, open(out, "w"))
print("ok", flush=True)
"""


def load():
    return os.getloadavg()


def build_fmu(dest, model):
    cmd = [sys.executable, str(ROOT / "build_fmu.py"), "--dest", str(dest)]
    cmd += ["--rom", str(model)] if model else []
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode:
        raise SystemExit(run.stderr.strip() or run.stdout.strip())
    return Path(dest) / "FaceFMU.fmu"


def fmu_runs(fmu, step, duration, repeat, schedules, fidelity="realtime"):
    sched = {s.muscle: [list(s.times), list(s.values)] for s in schedules}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        script = Path(tmp) / "run.py"
        script.write_text(FMPY_RUN)
        env = dict(os.environ, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1",
                   OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        run = subprocess.run([sys.executable, str(script), str(fmu), str(out), str(step),
                              str(duration), str(repeat), json.dumps(sched), fidelity],
                             capture_output=True, text=True, env=env, cwd=tmp)
        if not out.is_file():
            raise SystemExit(f"the fmpy run failed ({run.returncode}):\n"
                             f"{run.stdout[-2000:]}{run.stderr[-3000:]}")
        if run.returncode:
            print(f"(the fmpy process exited with {run.returncode} after finishing: "
                  "the known pythonfmu exit crash)")
        return json.loads(out.read_text())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fmu", type=Path, help="a built FMU with the model (default: build)")
    ap.add_argument("--model", type=Path, help="model file to pack (default: the cached "
                                               "model of the speech scene)")
    ap.add_argument("--step", type=float, default=5e-3, help="communication step (s)")
    ap.add_argument("--gesture", default="oop_ris")
    ap.add_argument("--repeat", type=int, default=5, help="runs of each (FMU: fresh instances)")
    ap.add_argument("--no-full", action="store_true", help="skip the full-order reference")
    ap.add_argument("--no-balanced", action="store_true",
                    help="skip the `balanced` fidelity through the FMU")
    ap.add_argument("--md", type=Path, help="write the figures as the gesture's row of this markdown table")
    args = ap.parse_args(argv)
    for var in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    import numpy as np
    from solver import configure_numba
    configure_numba()                      # the FMU's numba settings, in process too
    from solver.rom.accuracy import GESTURES
    from solver.rom.train import drive
    from solver.entry import open_simulation
    from solver.app.simulation import Simulation
    duration, schedules = GESTURES[args.gesture]
    print(f"load average before: {' '.join(f'{x:.2f}' for x in load())} "
          f"({os.cpu_count()} CPUs)")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        fmu = args.fmu or build_fmu(tmp, args.model)
        if not args.fmu:
            print(f"built the FMU with the model in {time.perf_counter() - t0:.1f} s")
        res = fmu_runs(fmu, args.step, duration, args.repeat, schedules)
        bal = None if args.no_balanced else \
            fmu_runs(fmu, args.step, duration, 1, schedules, "balanced")
    runs = res["runs"]
    best = min(runs, key=lambda r: r["wall_s"])
    walls = ", ".join(f"{r['wall_s']:.3f}" for r in runs)
    med = float(np.median([r["wall_s"] for r in runs]))
    print(f"FMU ({args.gesture}, {duration} s at {1e3 * args.step:g} ms steps, "
          f"{len(runs)} runs): wall {walls} s; best {best['wall_s']:.3f} s, real-time "
          f"factor {best['wall_s'] / duration:.2f} (median {med / duration:.2f}; cpu "
          f"{best['cpu_s']:.3f} s); initialization {best['init_s']:.2f} s")
    share = max(r["full_time"] for r in runs) / duration
    print(f"full model's share of the simulated time (rom_full_time): {100 * share:.0f} % "
          f"({max(r['fallbacks'] for r in runs)} handovers at most)")
    fmu_rows = np.array(best["rows"])

    rom = open_simulation("speech", fidelity="realtime")
    zero = rom.get_state()
    walls = []
    for _ in range(args.repeat):
        rom.set_state(zero)
        t0 = time.perf_counter()
        rows = drive(rom, schedules, duration, args.step)
        walls.append(time.perf_counter() - t0)
    rom_rows = np.array([[r["time"], r["lip_aperture"], r["lip_protrusion"],
                          r["contact_force"]] for r in rows])
    d = np.abs(rom_rows[:, 1:3] - fmu_rows[:, 1:3]).max(axis=0)
    print(f"in process (no FMU): wall {', '.join(f'{w:.3f}' for w in walls)} s; best "
          f"{min(walls):.3f} s, real-time factor {min(walls) / duration:.2f} (median "
          f"{float(np.median(walls)) / duration:.2f}); mode {rom.mode}; FMU - in process: "
          f"aperture {d[0]:.2g} mm, protrusion {d[1]:.2g} mm")

    ap = pr = rng_ap = rng_pr = float("nan")
    if not args.no_full:
        full = Simulation(rom.scene, loaded_anatomy=rom.anatomy)      # the full model
        t0 = time.perf_counter()
        frows = drive(full, schedules, duration, 5e-3)
        fwall = time.perf_counter() - t0
        every = int(round(5e-3 / args.step))
        sub = fmu_rows[::every]
        ap = max(abs(a[1] - b["lip_aperture"]) for a, b in zip(sub, frows))
        pr = max(abs(a[2] - b["lip_protrusion"]) for a, b in zip(sub, frows))
        rng_ap = np.ptp([b["lip_aperture"] for b in frows])
        rng_pr = np.ptp([b["lip_protrusion"] for b in frows])
        print(f"against the full-order model (coarse half face, 5 ms records, full order "
              f"{fwall:.1f} s wall): max error aperture {ap:.3f} mm (range {rng_ap:.2f} mm), "
              f"protrusion {pr:.3f} mm (range {rng_pr:.2f} mm)")
    bap = bpr = brtf = float("nan")
    if bal is not None:
        b = bal["runs"][0]
        brows = np.array(b["rows"])
        bap, bpr = np.abs(fmu_rows[:, 1:3] - brows[:, 1:3]).max(axis=0)
        brtf = b["wall_s"] / duration
        print(f"beside `balanced` through the same FMU (full order, finer face, "
              f"{1e3 * args.step:g} ms steps, 1 run): wall {b['wall_s']:.1f} s, real-time "
              f"factor {brtf:.1f}; realtime - balanced: max aperture {bap:.3f} mm (range "
              f"{np.ptp(brows[:, 1]):.2f} mm), protrusion {bpr:.3f} mm (range "
              f"{np.ptp(brows[:, 2]):.2f} mm)")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in load())}")
    if args.md:
        from solver.app.provenance import command, commit, upsert_row
        key = f"{args.gesture} ({duration} s, {1e3 * args.step:g} ms steps)"
        upsert_row(args.md, "| gesture | FMU real-time factor, best / median | in process, "
                   "best | max error aperture / protrusion (mm) | range (mm) | `balanced` "
                   "through the FMU: real-time factor | max error against `balanced` (mm) "
                   "| full model's share | command, commit |\n|---|---|---|---|---|---|---|"
                   "---|---|", key,
                   f"| {key} | {best['wall_s'] / duration:.2f} / {med / duration:.2f} | "
                   f"{min(walls) / duration:.2f} | {ap:.3f} / {pr:.3f} | {rng_ap:.2f} / "
                   f"{rng_pr:.2f} | {brtf:.1f} | {bap:.3f} / {bpr:.3f} | {100 * share:.0f} % | "
                   f"`{command('benchmarks/realtime_fmu.py')}`, {commit(ignore=[args.md])} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
