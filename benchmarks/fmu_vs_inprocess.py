"""The same gesture in process, through fmpy and through libcosim: wall times and ratios.

    python benchmarks/fmu_vs_inprocess.py [--anatomy generic,reference] [--fidelity balanced]
                                          [--scene speech] [--step 0.005] [--duration 0.3]
                                          [--masters inprocess,fmpy,libcosim]

Each run is a fresh process (numba kernels from the cache) that builds the model, then
steps the scene's activation schedule at the communication step: each step the
activations at its end are set and the model steps (what a master does with the FMU, and
what Simulation.step does in process). Only the stepping is timed. Prints per anatomy the
wall time of each master, its ratio to in-process, and the largest difference of the lip
aperture and protrusion from the in-process run (mm), and writes the table with its
command, commit and date to --out (docs/fmu_vs_inprocess.md; "" writes none). The
reference face is read from ../shared/data/reference-face (or $FACEFMU_REFERENCE_FACE)
and skipped where absent.
"""

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from solver.face.anatomy.reference import reference_face_dir

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = reference_face_dir()
OUT = ("lip_aperture", "lip_protrusion")

CHILD = r"""
import json, sys, time
mode, scene_name, anatomy, fidelity, step, duration, fmu = sys.argv[1:8]
step, duration = float(step), float(duration)
n = int(round(duration / step))
rows = []
if mode == "inprocess":
    from solver import configure_numba
    configure_numba()                      # the FMU's numba settings
    from solver.entry import open_simulation
    from solver.app.simulation import resolve_scene
    scene = resolve_scene(scene_name)
    sim = open_simulation(scene_name, anatomy=anatomy, fidelity=fidelity or None)
    t0 = time.perf_counter()
    for k in range(n):
        t = (k + 1) * step
        sim.set_activations({m: a for m, a in scene.activations(t).items()
                             if m in sim.face.muscles})
        assert sim.step(t).converged, t
        out = sim.outputs()
        rows.append([out[o] for o in ("lip_aperture", "lip_protrusion")])
    wall = time.perf_counter() - t0
else:
    from fmpy import extract, read_model_description
    md = read_model_description(fmu)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    params = {"scene": scene_name, "anatomy": anatomy, "fidelity": fidelity}
    # the schedule, read here from the scene without importing the FMU's solver package
    sched = json.loads(sys.argv[8])
    def acts(t):
        import numpy as np
        return {m: float(np.interp(t, s[0], s[1])) for m, s in sched.items()}
    if mode == "fmpy":
        from fmpy.fmi2 import FMU2Slave
        fmu_ = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu),
                         modelIdentifier=md.coSimulation.modelIdentifier, instanceName="face")
        fmu_.instantiate()
        fmu_.setupExperiment(startTime=0.0)
        fmu_.enterInitializationMode()
        for k, v in params.items():
            fmu_.setString([vr[k]], [v])
        fmu_.exitInitializationMode()
        t0 = time.perf_counter()
        for k in range(n):
            t = (k + 1) * step
            a = acts(t)
            fmu_.setReal([vr[m] for m in a], list(a.values()))
            fmu_.doStep(k * step, step)
            rows.append(fmu_.getReal([vr[o] for o in ("lip_aperture", "lip_protrusion")]))
        wall = time.perf_counter() - t0
        fmu_.terminate()
        fmu_.freeInstance()
    else:
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimManipulator import CosimManipulator
        from libcosimpy.CosimObserver import CosimObserver
        from libcosimpy.CosimSlave import CosimLocalSlave
        log_output_level(CosimLogLevel.WARNING)
        ex = CosimExecution.from_step_size(step_size=int(round(step * 1e9)))
        face = ex.add_local_slave(CosimLocalSlave(fmu_path=fmu, instance_name="face"))
        for k, v in params.items():
            ex.string_initial_value(face, vr[k], v)
        obs = CosimObserver.create_last_value()
        ex.add_observer(obs)
        man = CosimManipulator.create_override()
        ex.add_manipulator(man)
        t0 = time.perf_counter()
        for k in range(n):
            t = (k + 1) * step
            a = acts(t)
            man.slave_real_values(face, [vr[m] for m in a], list(a.values()))
            assert ex.step(1), t
            rows.append(obs.last_real_values(face, [vr[o] for o in ("lip_aperture", "lip_protrusion")]))
        wall = time.perf_counter() - t0
print(json.dumps({"wall_s": wall, "rows": rows}), flush=True)
"""


def schedule(scene_name, duration):
    """{muscle: (times, values)} of the scene's (ramp or piecewise-linear) schedules."""
    sys.path.insert(0, str(ROOT))
    from solver.app.simulation import resolve_scene
    scene = resolve_scene(scene_name)
    times = sorted({0.0, duration, *[t for s in scene.schedules for t in s.times
                                     if t < duration]})
    return {m: (times, [scene.activations(t)[m] for t in times])
            for m in {s.muscle for s in scene.schedules}}


def run(mode, scene, anatomy, fidelity, step, duration, fmu, sched):
    proc = subprocess.run([sys.executable, "-c", CHILD, mode, scene, anatomy, fidelity,
                           str(step), str(duration), str(fmu), json.dumps(sched)],
                          capture_output=True, text=True, cwd=ROOT)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        return {"error": (proc.stdout + proc.stderr)[-600:], "exit": proc.returncode}
    return json.loads(lines[-1]) | {"exit": proc.returncode}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--anatomy", default="generic,reference")
    ap.add_argument("--scene", default="speech")
    ap.add_argument("--fidelity", default="balanced")
    ap.add_argument("--step", type=float, default=0.005)
    ap.add_argument("--duration", type=float, default=0.3)
    ap.add_argument("--masters", default="inprocess,fmpy,libcosim")
    ap.add_argument("--out", default=str(ROOT / "docs" / "fmu_vs_inprocess.md"))
    args = ap.parse_args(argv)
    table = []

    def say(line):
        print(line, flush=True)
        table.append(line)

    masters = args.masters.split(",")
    sched = schedule(args.scene, args.duration)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", tmp],
                       check=True, stdout=subprocess.DEVNULL)
        fmu = Path(tmp) / "FaceFMU.fmu"
        say(f"scene {args.scene}, fidelity {args.fidelity!r}, {args.duration} s at "
            f"{args.step * 1e3:g} ms steps; wall time of the stepping")
        say(f"{'anatomy':10s}{'master':11s}{'wall (s)':>10s}{'ratio':>8s}"
              f"{'max diff (mm)':>15s}{'exit':>6s}")
        for anatomy in args.anatomy.split(","):
            spec = "generic" if anatomy == "generic" else str(REFERENCE)
            if anatomy == "reference" and not REFERENCE.is_dir():
                say(f"{anatomy:10s}skipped: no {REFERENCE}")
                continue
            base = None
            for mode in masters:
                res = run(mode, args.scene, spec, args.fidelity, args.step, args.duration,
                          fmu, sched)
                if "error" in res:
                    say(f"{anatomy:10s}{mode:11s} failed (exit {res['exit']}): "
                        f"{res['error']}")
                    continue
                base = base or res
                diff = max(abs(a - b) for r, q in zip(res["rows"], base["rows"])
                           for a, b in zip(r, q))
                say(f"{anatomy:10s}{mode:11s}{res['wall_s']:10.2f}"
                    f"{res['wall_s'] / base['wall_s']:8.2f}{diff:15.2e}{res['exit']:6d}")
    if args.out:
        from solver.app.provenance import commit as git_commit
        commit = git_commit()
        command = "python benchmarks/fmu_vs_inprocess.py " + " ".join(argv or sys.argv[1:])
        Path(args.out).write_text(
            "<!-- written by benchmarks/fmu_vs_inprocess.py; do not edit -->\n"
            f"`{command.strip()}` at commit {commit}, "
            f"{datetime.date.today().isoformat()}, {os.cpu_count()} cores:\n\n```\n"
            + "\n".join(table) + "\n```\n")


if __name__ == "__main__":
    main()
