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
--save a folder of each setting's outputs (NAME.npy, (k, 2) mm).
"""

import argparse
import csv
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
    args = ap.parse_args(argv)
    from solver.core.numba_config import configure_numba
    configure_numba()
    times, acts, jaw, csv_out = read_inputs(args.csv)
    configs = [parse_config(c) for c in (args.config or ["main=fidelity:"])]
    ref_name = args.reference or configs[0][0]
    results = {}
    for name, settings in configs:
        results[name] = replay(args.scene, settings, times, acts, jaw)
        o, c = results[name]
        if args.save:
            Path(args.save).mkdir(parents=True, exist_ok=True)
            np.save(Path(args.save) / f"{name}.npy", o)
        print(f"{name}: {c['wall']:.1f} s, {c['dof']} DOF, {c['substeps']} substeps, "
              f"{c['iterations']} Newton iterations, {c['factorizations']} factorizations, "
              f"{c['rejected']} rejected", flush=True)
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
                f"{commit()}, in one process, 2 cores.\n\n"
                + "\n".join(f"- {n}: `{', '.join(f'{k}={v!r}' for k, v in s.items())}`"
                            for n, s in configs) + "\n\n" + "\n".join(lines) + "\n")
        Path(args.md).write_text(text)


if __name__ == "__main__":
    main()
