"""Replay a co-simulation's inputs open loop through the face at several settings: what
each costs and how far its lip outputs fall from a reference setting's.

    python benchmarks/replay.py [--csv out/cosim/cosim.csv] [--scene default]
        [--config NAME=KEY:VALUE,KEY:VALUE ...] [--reference NAME] [--md FILE]

The CSV is examples/cosim_speech.py's: per communication step, the ten activations and the
jaw opening applied over it (rows at the step's end). Each --config names a setting: the
key `fidelity` (a preset of solver.app.fidelity, or "" for the scene's own) and any Scene
field (integrator, substep_tol, substep_rtol, max_substep, level, newton_rtol, ...), e.g.
`main=fidelity:` or `bdf2-fast=fidelity:fast,integrator:bdf2`. Each runs in this process
(the FMU runs the same Simulation), after its model is built; prints per setting the wall
time of the stepping, substeps, Newton iterations, factorizations, and the largest
difference of lip aperture and protrusion from the --reference setting's run (default: the
first) and from the CSV's own outputs. --md writes the table with its command and commit;
--save a folder of each setting's outputs (NAME.npy, (k, 2) mm). --before COMMIT runs
every setting on that commit's code too (a temporary git worktree; benchmarks/revision.py)
and then on this checkout's, each in a fresh process, in the same call: rows NAME@COMMIT
beside NAME.
"""

import argparse
import csv
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MUSCLES = ("LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM")
OUTPUTS = ("lip_aperture", "lip_protrusion")


def read_inputs(path):
    """(times (k,), activations list of dicts, jaw openings (k,) deg, outputs (k, 2) mm)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    times = np.array([float(r["time"]) for r in rows])
    acts = [{m: float(r[m]) for m in MUSCLES} for r in rows]
    jaw = np.array([float(r.get("jaw_opening") or 0.0) for r in rows])
    outs = np.array([[float(r[o]) for o in OUTPUTS] for r in rows])
    return times, acts, jaw, outs


def parse_config(text):
    """NAME=KEY:VALUE,... -> (name, {key: value}) with numbers and booleans converted."""
    name, _, body = text.partition("=")
    out = {}
    for item in filter(None, body.split(",")):
        k, _, v = item.partition(":")
        for conv in (int, float):
            try:
                v = conv(v)
                break
            except ValueError:
                pass
        out[k.strip()] = {"true": True, "false": False}.get(v, v) if isinstance(v, str) else v
    return name, out


def replay(scene, settings, times, acts, jaw):
    """Step the inputs through a Simulation at the settings; (outputs (k, 2), dict of
    costs: wall s, substeps, iterations, factorizations, rejected, cutbacks)."""
    from solver.app.simulation import Simulation
    settings = dict(settings)
    fidelity = settings.pop("fidelity", None) or None
    sim = Simulation(scene, fidelity=fidelity, **settings)
    outs = []
    cost = dict(substeps=0, iterations=0, factorizations=0, rejected=0, cutbacks=0)
    t0 = time.perf_counter()
    for t, a, j in zip(times, acts, jaw):
        sim.set_activations(a)
        if sim.face.jaw is not None:
            sim.set_jaw(j, None)
        st = sim.step(float(t))
        if not st.converged:
            raise RuntimeError(f"step to t = {t:.4g} s failed: {st.reason}")
        cost["substeps"] += st.substeps
        cost["iterations"] += st.newton_iterations
        cost["factorizations"] += st.factorizations
        cost["rejected"] += st.rejected
        cost["cutbacks"] += st.cutbacks
        o = sim.outputs()
        outs.append([o[k] for k in OUTPUTS])
    cost["wall"] = time.perf_counter() - t0
    cost["dof"] = sim.face.model.u.size
    return np.array(outs), cost


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--csv", default=str(ROOT / "out" / "cosim" / "cosim.csv"))
    ap.add_argument("--scene", default="default")
    ap.add_argument("--config", action="append", default=None)
    ap.add_argument("--reference", default=None)
    ap.add_argument("--md", default="")
    ap.add_argument("--save", default="", help="folder: each setting's outputs as NAME.npy")
    ap.add_argument("--before", default="",
                    help="a commit: run every setting on its code too, in the same call "
                         "(rows NAME@COMMIT)")
    ap.add_argument("--json", default="", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    configs = [parse_config(c) for c in (args.config or ["main=fidelity:"])]
    ref_name = args.reference or configs[0][0]
    times, acts, jaw, csv_out = read_inputs(args.csv)
    if args.before:
        from revision import checkout, describe, run_json
        rev = describe(args.before)
        sub = ["--csv", str(Path(args.csv).resolve()), "--scene", args.scene]
        sub += [a for c in (args.config or ["main=fidelity:"]) for a in ("--config", c)]
        with checkout(args.before) as code:
            old = run_json("benchmarks/replay.py", sub, code)
        new = run_json("benchmarks/replay.py", sub)
        results = {}
        for name, _ in configs:
            results[f"{name}@{rev}"] = (np.array(old[name][0]), old[name][1])
            results[name] = (np.array(new[name][0]), new[name][1])
        configs = [(n, s) for name, s in configs for n in (f"{name}@{rev}", name)]
    else:
        from solver.core.numba_config import configure_numba
        configure_numba()
        results = {}
        for name, settings in configs:
            results[name] = replay(args.scene, settings, times, acts, jaw)
            o, c = results[name]
            print(f"{name}: {c['wall']:.1f} s, {c['dof']} DOF, {c['substeps']} substeps, "
                  f"{c['iterations']} Newton iterations, {c['factorizations']} "
                  f"factorizations, {c['rejected']} rejected", flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps({n: (o.tolist(), c)
                                                   for n, (o, c) in results.items()}))
            return
    for name, (o, _) in results.items():
        if args.save:
            Path(args.save).mkdir(parents=True, exist_ok=True)
            np.save(Path(args.save) / f"{name}.npy", o)
    ref = results[ref_name][0]
    head = ("| setting | DOF | wall s | substeps | Newton iterations | factorizations | "
            f"vs {ref_name}: aperture / protrusion (mm) | vs the CSV (mm) |")
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    for name, settings in configs:
        o, c = results[name]
        d = np.abs(o - ref).max(axis=0)
        e = np.abs(o - csv_out).max(axis=0)
        lines.append(f"| {name} | {c['dof']} | {c['wall']:.1f} | {c['substeps']} | "
                     f"{c['iterations']} | {c['factorizations']} | {d[0]:.3f} / {d[1]:.3f} | "
                     f"{e[0]:.3f} / {e[1]:.3f} |")
    print("\n".join(lines))
    if args.md:
        from solver.app.provenance import commit, command
        text = (f"Generated by `{command('benchmarks/replay.py', sys.argv[1:])}` at "
                f"{commit()}, "
                + (f"rows NAME@{describe(args.before)} on that commit's code, one fresh process "
                   "per code version" if args.before else "in one process")
                + ", 2 cores.\n\n"
                + "\n".join(f"- {n}: `{', '.join(f'{k}={v!r}' for k, v in s.items())}`"
                            for n, s in configs) + "\n\n" + "\n".join(lines) + "\n")
        Path(args.md).write_text(text)


if __name__ == "__main__":
    main()
