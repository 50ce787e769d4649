"""Where a 5 ms step's time goes: the default scene at a fidelity, jaw still and jaw moving.

    python benchmarks/step_cost.py [--fidelity balanced] [--duration 0.1] [--step 0.005]
                                   [--opening 8] [--integrator bdf2|backward_euler]
                                   [--before COMMIT] [--md docs/generated/step_cost.md]

Drives the default scene (the paper's model: ten muscles, stiffening, inertia, damping,
lip and teeth contact) with the `speech` scene's OOP + RIS gesture at --step communication
steps in this process, twice: the jaw closed, and the jaw opening to --opening degrees and
closing again over the run (1 - cos). The stepping runs under cProfile; each function's
own time (cProfile's tottime, no overlap between rows) is put in one row:

* assembly kernels: the numba kernels of bricks, cables, damping and scatter;
* contact kernels: the numba kernels of contact geometry and penalties
  (solver/core/kernels/contact*.py);
* PARDISO factorizations and solves: the MKL calls (phase 22 and 33);
* solver Python: the rest of solver/ (terms, Newton, line search, contact search and
  bookkeeping, integrator);
* numpy and scipy: array operations and sparse products the solver's Python calls;
* other: the rest (the profiler's own share, the standard library).

The counts per step (substeps, Newton iterations, factorizations, solves, residual and
tangent assemblies) are the runs' own. Profiling adds its overhead to the Python rows;
the wall time without the profiler is printed beside it. --before COMMIT measures that
commit's code too (a temporary git worktree; benchmarks/revision.py), then this
checkout's, each in a fresh process, and puts the columns side by side. --md writes the
table with the command and commit.
"""

import argparse
import cProfile
import json
import math
import pstats
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROWS = ("assembly kernels", "contact kernels", "PARDISO factorizations", "PARDISO solves",
        "solver Python", "numpy and scipy", "other")


def _row(key):
    """The row of a cProfile key (file, line, function)."""
    path, _, name = key
    path = path.replace("\\", "/")
    if "/solver/core/kernels/contact" in path:
        return "contact kernels"
    if "/solver/core/kernels/" in path or "/solver/face/kernels" in path:
        return "assembly kernels"
    if path.endswith("solver/core/linsolve.py") and name == "call":
        return "PARDISO"
    if "/solver/" in path or "/facefmu/" in path:
        return "solver Python"
    if "numpy" in path or "scipy" in path or name.startswith("<method") or \
            name.startswith("<built-in method numpy") or "_sparsetools" in name:
        return "numpy and scipy"
    return "other"


def run(fidelity, duration, step, jaw, integrator, profile, newton=None):
    """Step the gesture; (seconds, counts dict, pstats.Stats or None). newton: Newton
    options to set (solver.core.newton.NewtonOptions fields)."""
    from solver.app.simulation import Simulation, resolve_scene
    gesture = resolve_scene("speech")
    sim = Simulation("default", fidelity=fidelity,
                     **({"integrator": integrator} if integrator else {}))
    for key, value in (newton or {}).items():
        setattr(sim.face.model.newton_options, key, value)
    lin = sim.face.model.linear_solver
    counts = dict(steps=0, substeps=0, iterations=0, factorizations=0, solves=0,
                  factor_s=0.0, solve_s=0.0)
    real_f, real_s = type(lin).factorize, type(lin).solve

    def factorize(self, *a, **k):
        t0 = time.perf_counter()
        try:
            return real_f(self, *a, **k)
        finally:
            counts["factor_s"] += time.perf_counter() - t0

    def solve(self, *a, **k):
        t0 = time.perf_counter()
        counts["solves"] += 1
        try:
            return real_s(self, *a, **k)
        finally:
            counts["solve_s"] += time.perf_counter() - t0
    type(lin).factorize, type(lin).solve = factorize, solve
    prof = cProfile.Profile() if profile else None
    n = int(round(duration / step))
    try:
        t0 = time.perf_counter()
        if prof:
            prof.enable()
        for k in range(1, n + 1):
            t = k * step
            sim.set_activations(gesture.activations(t))
            if jaw is not None:
                sim.set_jaw(jaw(t), 0.0)
            st = sim.step(t)
            if not st.converged:
                raise RuntimeError(f"step to t = {t:.4g} s failed: {st.reason}")
            counts["steps"] += 1
            counts["substeps"] += st.substeps
            counts["iterations"] += st.newton_iterations
            counts["factorizations"] += st.factorizations
        if prof:
            prof.disable()
        wall = time.perf_counter() - t0
    finally:
        type(lin).factorize, type(lin).solve = real_f, real_s
    return wall, counts, pstats.Stats(prof) if prof else None


def breakdown(stats, counts):
    """{row: seconds} from a profile (tottime per function, one row each)."""
    out = dict.fromkeys(ROWS, 0.0)
    pardiso = 0.0
    for key, (_, _, tottime, _, _) in stats.stats.items():
        row = _row(key)
        if row == "PARDISO":
            pardiso += tottime
        else:
            out[row] += tottime
    # the MKL calls split by the wrappers' timers (factorize, solve) in proportion
    both = counts["factor_s"] + counts["solve_s"]
    share = counts["factor_s"] / both if both else 0.0
    out["PARDISO factorizations"] = pardiso * share
    out["PARDISO solves"] = pardiso * (1.0 - share)
    return out


def measure(args, newton):
    """{column label: {"plain": s, "profiled": s, "counts": {...}, "rows": {row: s}}}: the
    jaw still and moving, each run twice without the profiler (the faster kept) and once
    with it, after a warm-up."""
    from solver.core.numba_config import configure_numba
    configure_numba()

    def cycle(t):
        return 0.5 * args.opening * (1.0 - math.cos(2.0 * math.pi * t / args.duration))
    runs = {"jaw still": None, f"jaw 0 -> {args.opening:g} -> 0 deg": cycle}
    run(args.fidelity, 2 * args.step, args.step, None, args.integrator, False, newton)
    cols = {}
    for label, jaw in runs.items():
        plain = min(run(args.fidelity, args.duration, args.step, jaw, args.integrator,
                        False, newton)[0] for _ in range(2))
        wall, counts, stats = run(args.fidelity, args.duration, args.step, jaw,
                                  args.integrator, True, newton)
        cols[label] = dict(plain=plain, profiled=wall, counts=counts,
                           rows=breakdown(stats, counts))
        print(f"{label}: {plain:.2f} s without the profiler, {wall:.2f} s with it", flush=True)
    return cols


def table(cols, step):
    """The markdown table of columns {label: measure()'s entry}."""
    lines = [f"| per {step * 1e3:g} ms step | " + " | ".join(cols) + " |",
             "|---|" + "---|" * len(cols)]

    def line(name, f):
        lines.append(f"| {name} | " + " | ".join(f(c, c["counts"]["steps"])
                                                 for c in cols.values()) + " |")
    line("wall time, no profiler (ms)", lambda c, n: f"{1e3 * c['plain'] / n:.0f}")
    line("wall time, profiled (ms)", lambda c, n: f"{1e3 * c['profiled'] / n:.0f}")
    for r in ROWS:
        line(f"- {r} (ms)", lambda c, n, r=r: f"{1e3 * c['rows'][r] / n:.1f} "
             f"({100 * c['rows'][r] / c['profiled']:.0f} %)")
    for key, label in (("substeps", "substeps"), ("iterations", "Newton iterations"),
                       ("factorizations", "factorizations"), ("solves", "solves")):
        line(label, lambda c, n, key=key: f"{c['counts'][key] / n:.2f}")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fidelity", default="balanced")
    ap.add_argument("--duration", type=float, default=0.1)
    ap.add_argument("--step", type=float, default=0.005)
    ap.add_argument("--opening", type=float, default=8.0)
    ap.add_argument("--integrator", default=None,
                    help="backward_euler or bdf2 (default: the fidelity's own)")
    ap.add_argument("--newton", action="append", default=[],
                    help="KEY=VALUE: a Newton option (NewtonOptions) for every run")
    ap.add_argument("--before", default="",
                    help="a commit: measure its code too, in the same call, and put its "
                         "columns beside this checkout's")
    ap.add_argument("--json", default="", help=argparse.SUPPRESS)
    ap.add_argument("--md", default="")
    args = ap.parse_args(argv)
    newton = {}
    for item in args.newton:
        key, _, value = item.partition("=")
        newton[key] = {"true": True, "false": False, "none": None}.get(value.lower(), value)
        if isinstance(newton[key], str):
            newton[key] = float(value)
    if args.json:                       # a run of revision.run_json: the columns only
        Path(args.json).write_text(json.dumps(measure(args, newton)))
        return
    if args.before:
        from revision import checkout, describe, run_json
        sub = ["--fidelity", args.fidelity, "--duration", str(args.duration), "--step",
               str(args.step), "--opening", str(args.opening)]
        sub += ["--integrator", args.integrator] if args.integrator else []
        sub += [a for item in args.newton for a in ("--newton", item)]
        rev = describe(args.before)
        print(f"before: {rev}", flush=True)
        with checkout(args.before) as code:
            before = run_json("benchmarks/step_cost.py", sub, code)
        print("after: this checkout", flush=True)
        after = run_json("benchmarks/step_cost.py", sub)
        cols = {}
        for label in after:
            cols[f"{label}, before ({rev})"] = before[label]
            cols[f"{label}, after"] = after[label]
    else:
        cols = measure(args, newton)
    text = table(cols, args.step)
    print(text)
    if args.md:
        from solver.app.fidelity import apply_fidelity
        from solver.app.simulation import resolve_scene
        integrator = args.integrator or \
            apply_fidelity(resolve_scene("default"), args.fidelity).integrator
        from solver.app.provenance import command, stamp
        Path(args.md).write_text(
            "# Where a step's time goes\n\n"
            f"Written by `{command('benchmarks/step_cost.py', argv)}` {stamp()}: the default "
            f"scene at `{args.fidelity}` ({integrator}"
            + "".join(f", {k} = {v}" for k, v in newton.items()) + "), driven by the `speech` scene's "
            f"OOP + RIS gesture for {args.duration:g} s at {args.step * 1e3:g} ms steps"
            + (f", measured on the code of commit {describe(args.before)} (before) and on "
               "this checkout's (after), one after the other in fresh processes"
               if args.before else ", in process")
            + ". Each row is the functions' own time under cProfile "
            "(benchmarks/step_cost.py says which functions go in which row); the share is "
            "of the profiled time; the wall time without the profiler is the faster of "
            f"two runs.\n\n{text}\n")
        print(f"wrote {args.md}")


if __name__ == "__main__":
    main()
