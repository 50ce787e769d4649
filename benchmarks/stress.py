"""The stress run: every hard case of solver/validation/stability/, its invariants, the step-halving
convergence check and (--fmu) the same cases through the built FMU with fmpy; a table.

    python benchmarks/stress.py [--quick] [--no-fmu] [--no-halving] [--cases NAME ...]
                                [--anatomy generic|reference|FOLDER] [--level LEVEL]
                                [--fidelity PRESET] [--config NAME ...]
                                [--out out/stress] [--doc FILE] [--jobs N]

With no options it runs every full case in process and through the FMU and rewrites
docs/stability.md whole (commit, date, wall time, the table, the failures). --quick runs
the CI versions of the cases; --cases a subset; --no-fmu skips the FMU rows; these write
the report to OUT only, unless --doc names a file. --anatomy, --level and --fidelity run
every case on another configuration (solver.validation.stability.configured: the reference face, the
generic face's paper level, a preset's mesh and tolerances); its rows are named
CASE@CONFIGURATION. --config runs the cases on several named configurations in one report
(CONFIGURATIONS below; `--config all`: every one). --part HEADING writes a report that a
page includes; docs/stability_configurations.md includes one per configuration:

    python benchmarks/stress.py --quick --config paper --part paper --doc docs/generated/stability_paper.md

--jobs N runs N cases at once, each in its own process (in process and through the FMU;
on a machine with N cores, about N times faster; each case's wall time then includes
the others' load). Writes OUT/stress.csv and OUT/stress.md; exits with 1 when a case
fails.

Columns: pass; steps (accepted communication steps) and refused ones; substeps, Newton
iterations, cutbacks (total) and worst cutbacks (in one step); min det F over all Gauss
points and steps; the deepest lip/lip and lip/teeth penetrations (mm; limited to the
contact tolerance only where the case has that contact on, else measured only); the
largest change of a lip output when every substep is halved (mm); memory growth (MB);
wall time (s). fmu rows: the case through the FMU, with the largest difference of its lip
outputs from the run in this process.
"""

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from solver.core.numba_config import configure_numba  # noqa: E402
from solver.face.anatomy.reference import reference_face_dir  # noqa: E402

configure_numba()                          # the FMU's numba settings, in process too
from solver.validation import stability as S  # noqa: E402
from solver.app.scene import parse_scene  # noqa: E402
from solver.app.provenance import commit  # noqa: E402
from table import report  # noqa: E402

# the configurations of --config: (anatomy, level, fidelity) for solver.validation.stability.configured;
# "coarse" is the cases' own (the coarse generic half face at the scene's tolerances)
CONFIGURATIONS = {"coarse": ("generic", None, None), "paper": ("generic", "paper", None),
                  "reference": ("reference", None, None),
                  "reference+balanced": ("reference", None, "balanced"),
                  "balanced": ("generic", None, "balanced"), "fast": ("generic", None, "fast"),
                  "realtime": ("generic", None, "realtime")}

KEYS = ["case", "pass", "contact", "steps", "refused", "substeps", "newton", "cutbacks",
        "worst_cutbacks", "min_det_f", "lip_pen_mm", "teeth_pen_mm", "halving_mm",
        "fmu_vs_solver_mm", "memory_mb", "wall_s"]


def _contact(case):
    sc = parse_scene(case.scene)
    on = [n for n, f in (("lips", sc.lip_contact), ("teeth", sc.teeth_contact)) if f]
    return "+".join(on) or "off"


def solver_row(case, run, halving):
    return {"case": case.name, "pass": "pass" if run.passed else "FAIL",
            "contact": _contact(case), "steps": run.steps, "refused": len(run.refused),
            "substeps": run.substeps, "newton": run.newton_iterations,
            "cutbacks": run.cutbacks, "worst_cutbacks": run.worst_cutbacks,
            "min_det_f": run.min_det_f, "lip_pen_mm": run.lip_penetration,
            "teeth_pen_mm": run.teeth_penetration, "halving_mm": halving,
            "memory_mb": run.memory_growth_mb, "wall_s": run.wall}


def _solve(case, halving):
    """One case in this process, and its halved run: (row, CaseRun, notes)."""
    print(f"-- {case.name}: {case.description}", flush=True)
    notes = []
    try:
        run = S.run_case(case)
    except Exception as exc:        # a configuration that cannot open: a FAIL row
        run = S.CaseRun(case.name)
        run.problem(None, f"{type(exc).__name__}: {exc}")
    change = float("nan")
    if halving and case.halving and run.passed:
        half = S.run_case(case.halved(), probe=False)
        change = S.halving_change(run, half)
        run.wall += half.wall
        if not half.passed:
            run.problems += [f"halved: {p}" for p in half.problems]
        limit = S.halving_limit(run)
        if not change <= limit:
            run.problems.append(f"halving every substep changed the lip outputs by "
                                f"{change:.3g} mm > {limit:.3g} mm")
    if run.fallbacks:
        notes.append(f"{case.name}: the reduced model handed the run to the full model "
                     f"({run.fallbacks} fallback{'s' * (run.fallbacks > 1)}; "
                     "solver.rom.simulation's trust check) and the full model went on")
    if case.equilibrium:
        notes.append(f"{case.name}: largest lip-output distance to the static "
                     "equilibrium at each tenth of the run (mm): "
                     + ", ".join(f"{d:.3g}" for d in run.equilibrium_distances))
    row = solver_row(case, run, change)
    print(f"   {case.name}: {row['pass']} in {run.wall:.1f} s" +
          "".join(f"\n   {p}" for p in run.problems), flush=True)
    return row, run, notes


def run_solver(selected, halving, jobs=1):
    """The cases in process, in `jobs` worker processes at once (spawned: fresh
    interpreters, no fork of numba's threads); rows in the cases' order."""
    if jobs > 1 and len(selected) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(min(jobs, len(selected)),
                                 mp_context=multiprocessing.get_context("spawn")) as pool:
            results = list(pool.map(_solve, selected, [halving] * len(selected)))
    else:
        results = [_solve(case, halving) for case in selected]
    rows, runs, notes = [], {}, []
    for case, (row, run, more) in zip(selected, results):
        rows.append(row)
        runs[case.name] = run
        notes += more
    return rows, runs, notes


def build_fmu(dest):
    run = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", str(dest)],
                         capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"FMU build failed:\n{run.stderr[-3000:]}")
    return Path(dest) / "FaceFMU.fmu"


def run_fmu(selected, runs, out, notes, fmu=None, jobs=1):
    """The cases through the FMU with fmpy, in `jobs` fmpy processes at once (the cases
    dealt out in turn)."""
    from solver.app.simulation import Simulation
    fmu = Path(fmu) if fmu else build_fmu(out / "fmu")
    bounds = S.output_bounds(Simulation(parse_scene(selected[0].scene)).anatomy)
    rows, problems, results = [], {}, {}
    with tempfile.TemporaryDirectory(prefix="facefmu-stress-") as tmp:
        tmp = Path(tmp)
        print(f"-- through the FMU ({fmu})", flush=True)
        t0 = time.perf_counter()
        procs = []
        for j in range(max(1, min(jobs, len(selected)))):
            specs = [S.fmu_spec(c, tmp / f"{c.name}.toml") for c in selected[j::jobs]]
            (tmp / f"cases{j}.json").write_text(json.dumps(specs))
            procs.append((j, subprocess.Popen(
                [sys.executable, str(ROOT / "tests" / "fmu_scripts" / "stress_case.py"),
                 str(fmu), str(tmp / f"out{j}.json"), str(tmp / f"cases{j}.json")],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp)))
        for j, proc in procs:
            stdout, stderr = proc.communicate()
            done = tmp / f"out{j}.json"
            if not ("ok" in stdout.splitlines() and done.is_file()):
                raise SystemExit(f"the FMU run crashed (exit {proc.returncode}):\n"
                                 f"{stdout[-2000:]}\n{stderr[-3000:]}")
            if proc.returncode != 0:
                raise SystemExit(f"the fmpy process finished every case, then exited with "
                                 f"{proc.returncode}:\n{stderr[-3000:]}")
            results.update(json.loads(done.read_text()))
        print(f"   {time.perf_counter() - t0:.1f} s", flush=True)
    for case in selected:
        res = results[case.name]
        found, m = S.check_fmu_run(case, res, runs.get(case.name), bounds)
        problems[case.name] = found
        ok = [s for s in res["statuses"] if s == 0]
        rows.append({"case": f"fmu:{case.name}", "pass": "FAIL" if found else "pass",
                     "contact": _contact(case), "steps": len(ok),
                     "refused": len(res["statuses"]) - len(ok),
                     "substeps": sum(r.get("substeps", 0) for r in res["rows"]),
                     "newton": sum(r.get("newton_iterations", 0) for r in res["rows"]),
                     **({"cutbacks": sum(r["cutbacks"] for r in res["rows"] if "cutbacks" in r),
                         "worst_cutbacks": max(r["cutbacks"] for r in res["rows"]
                                               if "cutbacks" in r)}
                        if any("cutbacks" in r for r in res["rows"]) else {}),
                     "fmu_vs_solver_mm": m["fmu_vs_solver"],
                     "memory_mb": m["memory_growth_mb"], "wall_s": res["wall"]})
        for p in found:
            print(f"   fmu:{case.name}: {p}")
    return rows, problems


def markdown(rows, command, notes, problems, wall, part=None, started=None):
    """The report; part: a heading (level 2) for a report that a page includes, which then
    leaves out the legend (the page explains the columns); started: commit() when the run
    began (named too where the checkout changed during the run)."""
    now = commit()
    started = started or now
    at = started if started == now else \
        f"{started} (the checkout was at {now} when it ended; the FMU is built mid-run)"
    def cell(v):
        if isinstance(v, float):
            return "-" if v != v else f"{v:.3g}"
        return str(v)
    lines = [f"## {part}" if part else "# Stability: the hard cases", "",
             f"Made by `{command}` at commit {at} on "
             f"{datetime.date.today().isoformat()}, {platform.machine()} "
             f"(Python {platform.python_version()}, {os.cpu_count()} cores), "
             f"{wall / 60:.1f} min in all (times are upper bounds: the machine may have "
             "had other work). Cases and checks: `solver/validation/stability/`; "
             "their quick versions are `tests/test_stability.py`.", ""]
    legend = [
             "Every case: no NaN or inf; det F > 0 at every Gauss point (column min_det_f, "
             "the smallest over all steps); lip outputs within bounds (aperture >= 0); "
             "dissipated energy never decreasing; statistics reported (cutbacks: total and "
             "the most in one step); a refused step leaves the state unchanged (runs of "
             "more than 1000 steps check every tenth step). Penetrations (mm) are measured "
             "outside the model: lip_pen_mm, lip-surface nodes inside bricks they do not "
             "belong to (depth: distance to the nearest lip surface), teeth_pen_mm, signed "
             f"distances to the teeth sheets, seen up to {S.PROBE_DEPTH:g} mm deep. They must "
             f"stay below {S.CONTACT_TOLERANCE} mm where the case has that contact on (column "
             "contact); elsewhere they are reported only. halving_mm: "
             "the largest change of a lip output at the communication points when every "
             f"substep is halved (limit {S.HALVING_TOLERANCE} mm at the default substep "
             f"tolerance, {S.HALVING_AT:g} mm, times sqrt(tol / {S.HALVING_AT:g}) at a looser "
             f"one, plus {S.HALVING_RELATIVE:.0%} of the case's largest lip-output excursion). "
             "fmu rows: the same case "
             "through the built FMU with fmpy; fmu_vs_solver_mm is the largest difference "
             f"from the run in this process (limit {S.FMU_MATCH_TOLERANCE} mm; both use the "
             f"scene's linear solver). Memory growth limit {S.MEMORY_LIMIT_MB} MB. pass n/a: "
             "the case does not apply to its configuration (the notes say why).", ""]
    lines += [] if part else legend
    lines += [" | ".join(KEYS), " | ".join("---" for _ in KEYS)]
    lines += [" | ".join(cell(r.get(k, "-")) for k in KEYS) for r in rows]
    if notes:
        lines += ["", "Notes:", ""] + [f"* {n}" for n in notes]
    failed = {k: v for k, v in problems.items() if v}
    lines += ["", "Failures:" if failed else "No failures.", ""]
    for name, found in failed.items():
        more = len(found) - 5
        lines += [f"* {name}:"] + [f"  * {p}" for p in found[:5]]
        lines += [f"  * ... and {more} more (the first 20 are kept)"] if more > 0 else []
    return "\n".join(lines) + "\n"


def main(argv=None):
    started = commit()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the CI versions of the cases")
    ap.add_argument("--no-fmu", action="store_true", help="skip the runs through the FMU")
    ap.add_argument("--fmu-path", help="a built FMU (default: build one into OUT/fmu)")
    ap.add_argument("--no-halving", action="store_true", help="skip the convergence check")
    ap.add_argument("--cases", nargs="+", help="only these cases")
    ap.add_argument("--out", default=str(ROOT / "out" / "stress"))
    ap.add_argument("--doc", help="also write the markdown report there (default: "
                    "docs/stability.md for the whole run)")
    ap.add_argument("--anatomy", default="generic",
                    help="generic, reference (../shared/data/reference-face) or a folder")
    ap.add_argument("--level", help="the generic face's level (coarse, medium, paper, fine)")
    ap.add_argument("--fidelity", help="a preset of solver.app.fidelity (fast, balanced, "
                    "accurate)")
    ap.add_argument("--config", nargs="+", choices=[*CONFIGURATIONS, "all"],
                    help="named configurations, one report (overrides --anatomy, --level "
                    "and --fidelity)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="cases run at once, each in its own process (default 1)")
    ap.add_argument("--part", metavar="HEADING",
                    help="write the report as a part of a page that includes it: this "
                    "level-2 heading, no legend")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs {args.jobs}: at least 1")
    reference = str(reference_face_dir())
    if args.anatomy == "reference":
        args.anatomy = reference
    configs = [(args.anatomy, args.level, args.fidelity)]
    if args.config:
        names = list(CONFIGURATIONS) if "all" in args.config else args.config
        configs = [CONFIGURATIONS[n] for n in names]
        configs = [(reference if a == "reference" else a, lv, f) for a, lv, f in configs]
        if not Path(reference).is_dir():
            print(f"no reference face at {reference}: its configurations are skipped")
            configs = [c for c in configs if c[0] != reference]
    other = args.anatomy != "generic" or args.level or args.fidelity or args.config
    if args.doc is None and not (args.quick or args.cases or args.no_fmu or args.no_halving
                                 or other):
        args.doc = str(ROOT / "docs" / "stability.md")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = [c for c in S.cases(full=not args.quick) if not args.cases or c.name in args.cases]
    if args.cases and len(base) != len(args.cases):
        known = [c.name for c in S.cases(full=not args.quick)]
        raise SystemExit(f"unknown case in {args.cases}; known: {known}")
    t0 = time.perf_counter()
    rows, problems, notes, fmu = [], {}, [], args.fmu_path
    skipped = []
    for anatomy, level, fidelity in configs:
        selected = [S.configured(c, anatomy, level, fidelity) for c in base]
        na = [c for c in selected if c.not_applicable]
        skipped += na
        rows += [{"case": c.name, "pass": "n/a", "contact": _contact(c)} for c in na]
        selected = [c for c in selected if not c.not_applicable]
        if not selected:
            continue
        solver_rows, runs, more = run_solver(selected, not args.no_halving, args.jobs)
        rows += solver_rows
        notes += more
        problems.update({c.name: runs[c.name].problems for c in selected})
        if not args.no_fmu:
            fmu = fmu or build_fmu(out / "fmu")
            fmu_rows, fmu_problems = run_fmu(selected, runs, out, notes, fmu, args.jobs)
            rows += fmu_rows
            problems.update({f"fmu:{k}": v for k, v in fmu_problems.items()})
    wall = time.perf_counter() - t0
    print()
    report(rows, KEYS, csv_path=out / "stress.csv")
    command = "python benchmarks/stress.py " + " ".join(a for a in (argv or sys.argv[1:]))
    notes += [f"{c.name} not run (n/a): {c.not_applicable}" for c in skipped]
    text = markdown(rows, command.strip(), notes, problems, wall, args.part, started)
    (out / "stress.md").write_text(text)
    if args.doc:
        Path(args.doc).write_text(text)
    failed = [k for k, v in problems.items() if v]
    print(f"\n{len(rows) - len(failed) - len(skipped)} of {len(rows)} passed, "
          f"{len(skipped)} not applicable, in {wall / 60:.1f} min"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
