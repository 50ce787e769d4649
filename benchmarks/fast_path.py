"""The full-order solver's defaults against full Newton: wall time of a lip gesture.

    python benchmarks/fast_path.py [--only a|b] [--quick] [--duration S] [--paths old,new]
                                   [--linear-solver auto|pardiso|superlu] [--profile]
                                   [--md FILE]

Scene (solver.app.gestures.gesture): transient, OOP 0 -> 1 and RIS 0 -> 0.5 over 0-0.15 s,
held to 0.3 s, lip and teeth contact on, lip aperture and protrusion recorded every 10 ms,
at the `balanced` fidelity preset's integrator and tolerances (the scene names it;
solver.app.fidelity.PRESETS, docs/presets.md) on

    a  the reference (ANSYS) face, full face (../shared/data/reference-face or
       $FACEFMU_REFERENCE_FACE; skipped where absent)      target 27 s wall for 0.3 s
    b  the generic face at level "paper" (the paper's own mesh: one brick row per layer,
       not the preset's two), half face                    target 15 s wall for 0.3 s

Each case runs with each path (build time apart, the numba kernels compiled beforehand):

    old  full Newton: a factorization at every iteration, predictor u_n + h v_n with a
         second try from u_n (solver.core.transient)
    new  the defaults: factorization reuse (NewtonOptions.reuse, refactor_ratio) and
         the integrator's warm start (Transient.predictor)

and prints per case and path: wall time (s), real-time factor (wall / simulated time),
substeps, Newton iterations, factorizations, assemblies with tangent, residual-only
evaluations, the deepest contact penetration at the recorded times (penetration_mm, the
contact terms' own gaps), and the largest difference (mm) between the paths' lip
aperture and protrusion over the recorded times (the paths share the convergence
criteria, so they must agree to a small multiple of the Newton tolerance), and probe_s,
the seconds of a fixed workload (probe(): a PARDISO factorization and solves, a dense
product) just before and after the run: the machine's speed drifts, by tens of percent
within minutes on a shared machine, so wall times compare only at similar probes, or one
run after the other. A run whose
step fails after every cutback is reported (column failed) with its figures up to there.
--profile instead runs the new path under cProfile for --duration (default 0.05 s) and prints the
top functions.
--quick: 0.05 s of the gesture. --linear-solver: the scene's (default auto: PARDISO in
single precision where it installs; the FMU takes SuperLU). --md FILE writes the table as
markdown too.

Experiments (docs/dev-notes/fast_path.md): ``--set KEY=VALUE`` (repeatable) changes one knob of
every run: ``transient.X`` an attribute of solver.core.transient.Transient (tol, max_substep,
fixed_step, predictor), ``newton.X`` a field of solver.core.newton.NewtonOptions (rtol, utol,
refactor_ratio, contact_update), ``contact.X`` an attribute of each contact term (smoothing,
penalty), ``lips.X`` and ``teeth.X`` of the lip or the teeth terms only, ``damping.X`` of the
damping term (refresh); ``--contact both|teeth|lips|none`` the
contact terms built. The table then gains the column "set". ``--records FILE`` saves
the recorded outputs (JSON, per case and path); ``--against FILE`` adds the columns
vs_aperture_mm and vs_protrusion_mm, the largest differences from the same case and path
in such a file (e.g. the run without --set).
"""

import argparse
import cProfile
import json
import pstats
import sys
import time
from pathlib import Path

if __package__ in (None, ""):                     # run as a script: the repository root
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.table import report  # noqa: E402
from solver.app.gestures import gesture  # noqa: E402
from solver.face.anatomy.reference import reference_face_dir  # noqa: E402

REFERENCE_FACE = reference_face_dir()
DURATION, QUICK = 0.3, 0.05                       # s
GROUPS = ("transient", "newton", "damping", "contact", "lips", "teeth")     # of --set
CASES = {"a": dict(anatomy=str(REFERENCE_FACE), half=False),
         "b": dict(anatomy="generic", level="paper", rows=1, half=True)}
TARGETS = {"a": 27.0, "b": 15.0}                 # s wall for 0.3 s
# the options of each path: NewtonOptions fields and Transient attributes
PATHS = {"old": {"newton": dict(reuse=False), "transient": {}},
         "new": {"newton": {}, "transient": {}}}


def build(case, duration, path, linear_solver="auto", knobs=(), contact="both"):
    """A Simulation of the gesture for case 'a' | 'b', set up for path 'old' | 'new', with
    the knobs [(KEY, value)] of --set applied last."""
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    sim = Simulation(parse_scene(gesture(duration, contact)), linear_solver=linear_solver,
                     **CASES[case])
    opts = PATHS[path]
    for k, v in opts["newton"].items():
        setattr(sim.face.model.newton_options, k, v)
    for k, v in opts["transient"].items():
        setattr(sim.integrator, k, v)
    for key, value in knobs:
        for target in _knob_targets(sim, key):
            setattr(target, key.split(".", 1)[1], value)
    return sim


def _knob_targets(sim, key):
    """The objects that a --set KEY addresses (its group one of GROUPS)."""
    group = key.split(".", 1)[0]
    if group == "transient":
        return [sim.integrator]
    if group == "newton":
        return [sim.face.model.newton_options]
    if group == "damping":
        return [sim.integrator.damping]
    if group == "contact":
        return list(sim.contact)
    return [t for t in sim.contact if ("teeth" in t.name) == (group == "teeth")]


def parse_knob(text):
    """'group.name=value' -> ('group.name', value as int, float, bool or str); the group
    one of GROUPS."""
    key, sep, raw = text.partition("=")
    if not sep or "." not in key:
        raise argparse.ArgumentTypeError(f"{text!r}: expected group.name=value")
    if key.split(".", 1)[0] not in GROUPS:
        raise argparse.ArgumentTypeError(f"{text!r}: the group must be one of "
                                         f"{', '.join(GROUPS)}")
    for cast in (int, float):
        try:
            return key, cast(raw)
        except ValueError:
            pass
    return key, {"true": True, "false": False}.get(raw.lower(), raw)


def probe(n=26, reps=3):
    """Seconds of a fixed workload (the best of reps): a 3D Laplacian of n^3 unknowns
    factorized by the project's PARDISO in single precision (MKL_NUM_THREADS as set) and
    solved ten times, and a dense 600 x 600 product: a gauge of the machine's speed at the
    time of a run, whose wall time drifts with it (docs/dev-notes/fast_path.md)."""
    import numpy as np
    import scipy.sparse as sp
    from solver.core.linsolve import available, make_solver
    if "pardiso-single" not in available():
        return float("nan")
    d = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    eye = sp.identity(n)
    K = (sp.kron(sp.kron(d, eye), eye) + sp.kron(sp.kron(eye, d), eye)
         + sp.kron(sp.kron(eye, eye), d) + 1e-3 * sp.identity(n ** 3)).tocsr()
    b = np.ones(n ** 3)
    A = np.random.default_rng(0).standard_normal((600, 600))
    lin, best = make_solver("pardiso-single"), np.inf
    lin.factorize(K)                                      # the analysis, once
    for _ in range(reps):
        t0 = time.perf_counter()
        lin.factorize(K)
        for _ in range(10):
            lin.solve(b)
        A @ A
        best = min(best, time.perf_counter() - t0)
    lin.release()
    return best


def run(case, duration, path, linear_solver="auto", knobs=(), contact="both"):
    """One run: a row of figures and the recorded outputs; probe_s: probe() before and
    after it."""
    before = probe()
    t0 = time.perf_counter()
    sim = build(case, duration, path, linear_solver, knobs, contact)
    t_build = time.perf_counter() - t0
    sysm = sim.face.model.system()
    lin = sim.face.model.linear_solver
    f0 = getattr(lin, "factorizations", 0)
    c0 = dict(sysm.counters)
    totals = {"substeps": 0, "newton_its": 0, "cutbacks": 0, "penetration_mm": 0.0}
    t0 = time.perf_counter()
    rows, failed = [], ""
    try:
        sim.run(on_record=lambda s, row: (_count(s, totals), rows.append(row)))
    except RuntimeError as exc:                   # a step failed after every cutback
        failed = str(exc)
    wall = time.perf_counter() - t0
    row = {"case": case, "path": path, "solver": lin.name, "dof": 3 * sim.anatomy.mesh.n_nodes,
           "build_s": t_build, "wall_s": wall, "rtf": wall / duration,
           **totals,
           "factorizations": getattr(lin, "factorizations", 0) - f0,
           "assemblies": sysm.counters["assemblies"] - c0["assemblies"],
           "residuals": sysm.counters["residuals"] - c0["residuals"],
           "failed": failed or "-"}
    sim.release()
    row["probe_s"] = f"{before:.3f} / {probe():.3f}"
    return row, rows


def _count(sim, totals):
    """Add the statistics of the simulation's last step to totals, and keep the deepest
    contact penetration (mm) at the recorded times."""
    for term in sim.contact:
        totals["penetration_mm"] = max(totals["penetration_mm"], term.max_penetration)
    if sim.t > 0:
        totals["substeps"] += sim.last.substeps
        totals["newton_its"] += sim.last.newton_iterations
        totals["cutbacks"] += sim.last.cutbacks


def max_diff(rows, ref, key):
    """Largest difference over the times both runs recorded (a failed run stops early)."""
    return max(abs(a[key] - b[key]) for a, b in zip(rows, ref))


def warm_up():
    """Compile (or load) the numba kernels outside the timings: a few steps, coarse face."""
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    sim = Simulation(parse_scene(gesture(0.02)), level="coarse", half=True)
    sim.run()
    sim.release()


def profile(case, duration, path, top=25):
    sim = build(case, duration, path)
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    sim.run()
    prof.disable()
    print(f"case {case}, path {path}, {duration} s simulated: "
          f"{time.perf_counter() - t0:.2f} s wall under cProfile; "
          f"counters {sim.face.model.system().counters}, factorizations "
          f"{getattr(sim.face.model.linear_solver, 'factorizations', '?')}")
    seconds = sim.face.model.system().term_seconds
    print("assembly time per term (s): " + ", ".join(f"{k} {v:.2f}" for k, v in seconds.items()))
    pstats.Stats(prof).sort_stats("tottime").print_stats(top)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=sorted(CASES))
    ap.add_argument("--quick", action="store_true", help=f"{QUICK} s of the gesture")
    ap.add_argument("--duration", type=float)
    ap.add_argument("--paths", default="old,new")
    ap.add_argument("--linear-solver", default="auto")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--md")
    ap.add_argument("--set", dest="knobs", action="append", type=parse_knob, default=[],
                    metavar="GROUP.NAME=VALUE")
    ap.add_argument("--contact", choices=("both", "teeth", "lips", "none"), default="both")
    ap.add_argument("--records", type=Path)
    ap.add_argument("--against", type=Path)
    args = ap.parse_args(argv)
    against = json.loads(args.against.read_text()) if args.against else None
    saved = {}
    cases = [args.only] if args.only else sorted(CASES)
    if not REFERENCE_FACE.is_dir() and "a" in cases:
        print(f"case a skipped: no reference face at {REFERENCE_FACE}")
        cases.remove("a")
    paths = args.paths.split(",")
    warm_up()
    if args.profile:
        for case in cases:
            profile(case, args.duration or QUICK, paths[-1])
        return 0
    duration = args.duration or (QUICK if args.quick else DURATION)
    table = []
    for case in cases:
        runs = {}
        for path in paths:
            row, rec = run(case, duration, path, args.linear_solver, args.knobs,
                           args.contact)
            runs[path] = rec
            saved[f"{case}/{path}"] = rec
            if against is not None:
                other = against.get(f"{case}/{path}", [])
                row["vs_aperture_mm"] = max_diff(rec, other, "lip_aperture") if other else "-"
                row["vs_protrusion_mm"] = max_diff(rec, other, "lip_protrusion") if other \
                    else "-"
            ref = runs[paths[0]]
            row["d_aperture_mm"] = max_diff(rec, ref, "lip_aperture")
            row["d_protrusion_mm"] = max_diff(rec, ref, "lip_protrusion")
            row["aperture_end_mm"] = rec[-1]["lip_aperture"]
            row["protrusion_end_mm"] = rec[-1]["lip_protrusion"]
            row["end_s"] = rec[-1]["time"]
            row["target_s"] = TARGETS[case] * duration / DURATION
            row["set"] = " ".join(f"{k}={v}" for k, v in args.knobs) + (
                f" contact={args.contact}" if args.contact != "both" else "") or "-"
            table.append(row)
            print(f"  {case} {path}: {row['wall_s']:.2f} s to t = {row['end_s']:.3f} s "
                  f"{row['failed']}", flush=True)
    keys = ["case", "path", "solver", "dof", "build_s", "wall_s", "target_s", "rtf", "substeps",
            "newton_its", "factorizations", "assemblies", "residuals", "cutbacks",
            "penetration_mm",
            "d_aperture_mm", "d_protrusion_mm", "aperture_end_mm", "protrusion_end_mm",
            "probe_s", "failed"] + (["set"] if args.knobs or args.contact != "both" else []) + (
                ["vs_aperture_mm", "vs_protrusion_mm"] if against is not None else [])
    if args.records:
        args.records.write_text(json.dumps(saved))
    print(f"\ngesture of {duration} s at the balanced preset (wall times; the machine may "
          f"be shared)")
    report(table, keys)
    if args.md:
        import contextlib
        with open(args.md, "w") as fh, contextlib.redirect_stdout(fh):
            report(table, keys)
    return 0


if __name__ == "__main__":
    sys.exit(main())
