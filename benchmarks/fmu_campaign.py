"""A randomized campaign through the FMU: random schedules of all ten muscles, random
communication steps, lip and teeth contact on; every failure reproducible from its seed.

    python benchmarks/fmu_campaign.py [--seeds 0-199] [--duration 0.1] [--fidelity balanced]
                                      [--level coarse|medium|fine] [--batch 20] [--jobs 1]
                                      [--keep DIR] [--doc FILE]

Schedule of seed s (``schedule(s, duration)``, numpy's generator seeded s): communication
steps of a size drawn log-uniformly between 0.1 and 20 ms (rounded to 0.1 ms) until
`duration` is reached, each with new activations of all ten muscles, uniform in [0, 1].
FaceFMU (built once by build_fmu.py) runs the default scene at --fidelity (or, with
--level, on that generic half-face mesh level at the scene's own tolerances) through fmpy, in
fresh processes of --batch seeds each, --jobs of them at a time. A seed passes when every
doStep returns fmi2OK, the outputs stay finite with lip_aperture >= 0, the state
serialized at the end has no lip node inside the other lip and none behind the teeth by
more than the contact tolerance (solver.validation.stability.Probe, outside the model), and its
process exits with status 0.
Prints one line per seed and the failing seeds; rerun one with --seeds S; --doc writes
the same as a markdown report (the command, commit, date and wall time in its header):

    python benchmarks/fmu_campaign.py --jobs 2 --doc docs/campaign.md

Exits 1 on a failure.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MUSCLES = ("LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM")
SHORTEST, LONGEST = 1e-4, 0.02          # s: the range of the communication steps

CHILD = r'''
import json, math, sys
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
fmu_path, fidelity, level, jobs_path, out_dir = sys.argv[1:6]
jobs = json.load(open(jobs_path))
md = read_model_description(fmu_path)
vr = {v.name: v.valueReference for v in md.modelVariables}
unzip = extract(fmu_path)
outs = ["lip_aperture", "lip_protrusion", "lip_width", "contact_force"]
for job in jobs:
    f = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName=f"s{job['seed']}")
    f.instantiate()
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setString([vr["fidelity"]], [fidelity])
    if level:
        f.setString([vr["level"]], [level])
        f.setBoolean([vr["half_face"]], [True])
    f.exitInitializationMode()
    t, res = 0.0, {"seed": job["seed"], "problem": "", "steps": 0, "cutbacks": 0}
    for h, acts in job["steps"]:
        f.setReal([vr[m] for m in acts], list(acts.values()))
        try:
            f.doStep(t, h)
        except FMICallException as exc:
            res["problem"] = f"doStep at t = {t:.6g} s (h = {h:g} s) returned status {exc.status}"
            break
        t += h
        res["steps"] += 1
        res["cutbacks"] += f.getInteger([vr["cutbacks"]])[0]
        y = dict(zip(outs, f.getReal([vr[o] for o in outs])))
        if not all(math.isfinite(v) for v in y.values()) or y["lip_aperture"] < 0:
            res["problem"] = f"outputs at t = {t:.6g} s: {y}"
            break
    res["t"], res["outputs"] = t, y if res["steps"] else {}
    state = f"{out_dir}/seed{job['seed']}.state"
    open(state, "wb").write(bytes(f.serializeFMUstate(f.getFMUstate())))
    res["state"] = state
    f.terminate()
    f.freeInstance()
    print("RESULT " + json.dumps(res), flush=True)
print("ok", flush=True)
'''


def schedule(seed, duration):
    """[(step size s, {muscle: activation})] of seed, covering duration."""
    rng = np.random.default_rng(seed)
    steps, t = [], 0.0
    while t < duration - 1e-12:
        h = round(float(np.exp(rng.uniform(np.log(SHORTEST), np.log(LONGEST)))), 4)
        h = min(max(h, SHORTEST), round(duration - t, 4) or SHORTEST)
        steps.append((h, {m: float(a) for m, a in zip(MUSCLES, rng.uniform(0, 1, 10))}))
        t += h
    return steps


def seeds(text):
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def probe_for(fidelity, level=None):
    """The penetration probe of the FMU's default model at this fidelity (level: on that
    generic half-face level instead)."""
    sys.path.insert(0, str(ROOT))
    from solver.entry import open_simulation
    from solver.validation.stability import Probe
    sim = (open_simulation("default", level=level, half=True) if level else
           open_simulation("default", fidelity=fidelity or None))
    return Probe(sim.anatomy)


def penetrations(probe, state_file):
    import io
    with np.load(io.BytesIO(Path(state_file).read_bytes())) as z:
        u = z["sim.u"].reshape(-1, 3)
    return probe.penetrations(u)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-199", help="e.g. 0-199 or 3,17,40-45")
    ap.add_argument("--duration", type=float, default=0.1, help="s per schedule")
    ap.add_argument("--fidelity", default="balanced")
    ap.add_argument("--level", choices=("coarse", "medium", "fine"),
                    help="the generic half face at this mesh level instead of --fidelity")
    ap.add_argument("--batch", type=int, default=20, help="seeds per fmpy process")
    ap.add_argument("--jobs", type=int, default=1, help="fmpy processes at a time")
    ap.add_argument("--keep", help="build into and keep this folder")
    ap.add_argument("--doc", help="write a markdown report there")
    args = ap.parse_args(argv)
    todo = seeds(args.seeds)
    tmp = None if args.keep else tempfile.TemporaryDirectory(prefix="fmu-campaign-")
    base = Path(args.keep or tmp.name)
    model = f"level {args.level!r}" if args.level else f"fidelity {args.fidelity!r}"
    print(f"{len(todo)} random schedules of {args.duration} s (steps {SHORTEST * 1e3:g} to "
          f"{LONGEST * 1e3:g} ms, all ten muscles), default scene, {model}, lip and teeth "
          f"contact; seeds {args.seeds}", flush=True)
    rows, failed, wall = run_campaign(todo, args.duration, "" if args.level else args.fidelity,
                                      args.level, args.batch, args.jobs, base, log=print)
    print(f"\n{len(todo) - len(failed)} of {len(todo)} schedules passed in {wall:.0f} s"
          + (f"; failed seeds: {' '.join(map(str, sorted(failed)))}" if failed else ""))
    for s, p in sorted(failed.items()):
        print(f"  seed {s}: {p}  (python benchmarks/fmu_campaign.py --seeds {s} "
              f"--duration {args.duration} "
              + (f"--level {args.level})" if args.level else f"--fidelity {args.fidelity!r})"))
    if args.doc:
        from solver.validation.stability import CONTACT_TOLERANCE
        write_doc(args, argv, todo, rows, failed, wall, CONTACT_TOLERANCE)
    if tmp:
        tmp.cleanup()
    return 1 if failed else 0


def run_campaign(todo, duration, fidelity, level, batch, jobs, base, log=None):
    """Run the seeds todo (schedules of `duration` s) through FaceFMU built into base, at
    fidelity ("" with level: that mesh level at the scene's tolerances), in fmpy processes of
    `batch` seeds, `jobs` at a time. Returns (rows [(seed, steps, cutbacks, lip and teeth
    penetration mm, "pass" or the problem)], failed {seed: problem}, wall s); log: a
    callable for each seed's line."""
    from solver.validation.stability import CONTACT_TOLERANCE
    base = Path(base)
    base.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", str(base)],
                   check=True, stdout=subprocess.DEVNULL)
    fmu = base / "FaceFMU.fmu"
    probe = probe_for(fidelity, level)
    failed, rows, t0 = {}, [], time.perf_counter()

    def run_batch(i):
        part = [{"seed": s, "steps": schedule(s, duration)} for s in todo[i:i + batch]]
        jobs_path = base / f"jobs{i}.json"
        jobs_path.write_text(json.dumps(part))
        env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1") \
            if jobs > 1 else None                      # one core per process
        proc = subprocess.run([sys.executable, "-c", CHILD, str(fmu), fidelity,
                               level or "", str(jobs_path), str(base)],
                              capture_output=True, text=True, cwd=base, env=env)
        return part, proc

    with ThreadPoolExecutor(max(1, jobs)) as pool:
        for part, proc in pool.map(run_batch, range(0, len(todo), batch)):
            done = {}
            for line in proc.stdout.splitlines():
                if line.startswith("RESULT "):
                    r = json.loads(line[7:])
                    done[r["seed"]] = r
            for job in part:
                s = job["seed"]
                r = done.get(s)
                if r is None:
                    failed[s] = (f"no result (process exit {proc.returncode}): "
                                 f"{proc.stderr[-300:]}")
                    continue
                problem = r["problem"]
                lips, teeth = penetrations(probe, r["state"])
                if not problem and max(lips, teeth) > CONTACT_TOLERANCE:
                    problem = f"penetration lips {lips:.3f} mm, teeth {teeth:.3f} mm"
                if problem:
                    failed[s] = problem
                rows.append((s, len(job["steps"]), r["cutbacks"], lips, teeth,
                             problem or "pass"))
                if log:
                    log(f"seed {s:4d}: {len(job['steps']):4d} steps, {r['cutbacks']:3d} "
                        f"cutbacks, lips {lips:.3f} teeth {teeth:.3f} mm: {problem or 'pass'}")
            if proc.returncode != 0 and all(job["seed"] in done for job in part):
                for job in part:
                    failed.setdefault(job["seed"], f"the process exited with {proc.returncode}")
    return rows, failed, time.perf_counter() - t0


def write_doc(args, argv, todo, rows, failed, wall, tolerance):
    """The campaign as a markdown report at args.doc."""
    import datetime
    import platform
    sys.path.insert(0, str(ROOT))
    from solver.app.provenance import commit
    command = "python benchmarks/fmu_campaign.py " + " ".join(argv or sys.argv[1:])
    lines = ["# Randomized campaign through the FMU", "",
             f"Made by `{command.strip()}` at commit {commit()} on "
             f"{datetime.date.today().isoformat()}, {platform.machine()} (Python "
             f"{platform.python_version()}), {wall / 60:.1f} min. Each seed: a schedule of "
             f"{args.duration:g} s, communication steps log-uniform between "
             f"{SHORTEST * 1e3:g} and {LONGEST * 1e3:g} ms, each with new activations of all "
             f"ten muscles uniform in [0, 1]; the default scene at "
             + (f"mesh level `{args.level}` (half face)" if args.level else
                f"fidelity `{args.fidelity}`") + ", lip and teeth contact on, through fmpy. "
             "A seed passes when "
             "every doStep returns fmi2OK, the outputs stay finite with lip_aperture >= 0, "
             "the final state has no lip node inside the other lip and none behind the "
             f"teeth by more than {tolerance} mm (measured outside the model), and its "
             "process exits with status 0. Rerun a seed with `--seeds S`.", "",
             f"**{len(todo) - len(failed)} of {len(todo)} schedules passed.**", "",
             "| seed | steps | cutbacks | lips (mm) | teeth (mm) | result |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {s} | {n} | {c} | {lp:.3f} | {tt:.3f} | {res} |"
              for s, n, c, lp, tt, res in rows]
    missing = sorted(set(failed) - {r[0] for r in rows})
    lines += [f"| {s} | - | - | - | - | {failed[s]} |" for s in missing]
    Path(args.doc).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
