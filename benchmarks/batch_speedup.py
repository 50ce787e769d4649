"""Batch co-simulation on dask: the speed-up of 2 workers over 1 on this machine.

    python benchmarks/batch_speedup.py [--utterances 20] [--window 0.075] [--fidelity fast]
                                       [--workers 1 2] [--md docs/generated/batch_speedup.md]

Builds FaceFMU and LipMotorControl from this checkout, makes --utterances seeded random
utterances of two target windows of --window seconds each (pairs of the identified
targets, examples/motor_control/inverse_model.json), and runs them through
facefmu.batch on a LocalCluster of each --workers count (one-thread workers; the kernels
warmed before the clock starts). Prints per worker count the batch's wall time (from the
first submission to the last result; the cluster's start and warm-up apart), the
utterances per minute, the speed-up over the first count, and whether every run's
trajectories equal the first count's. --md writes the table with its command and commit.
"""

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))


def utterances(folder, n, window, seed=1):
    """n target files of two windows each (seeded pairs of the identified targets)."""
    from facefmu.batch import from_targets
    base = json.loads((ROOT / "examples" / "motor_control" / "inverse_model.json")
                      .read_text())["targets"]
    rng = np.random.default_rng(seed)
    paths = []
    for k in range(n):
        i, j = rng.choice(len(base), 2, replace=False)
        p = Path(folder) / f"u{k:02d}.json"
        p.write_text(json.dumps([dict(base[i], duration=window),
                                 dict(base[j], duration=window)]))
        paths.append(p)
    return from_targets(paths)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--utterances", type=int, default=20)
    ap.add_argument("--window", type=float, default=0.075)
    ap.add_argument("--fidelity", default="fast")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--md", default="")
    args = ap.parse_args(argv)
    from cosim_speech import build_fmus, speech_system
    from facefmu import speech
    from facefmu.batch import Batch
    rows, first = [], None
    with tempfile.TemporaryDirectory() as tmp:
        face, control = build_fmus(tmp)
        system = speech_system(face, control, 0.005)
        system.initial["face"]["fidelity"] = args.fidelity
        records = speech.records(system)
        utts = utterances(tmp, args.utterances, args.window)
        simulated = sum(u.stop for u in utts)
        for n in args.workers:
            t0 = time.perf_counter()
            with Batch(system, records, n_workers=n) as batch:
                batch.warmup()
                ready = time.perf_counter() - t0
                t1 = time.perf_counter()
                result = batch.run(utts, progress=False)
                wall = time.perf_counter() - t1
            failed = [s for s in result.summary if not s["ok"]]
            same = first is None or all(result.trajectories[u.name] == first[u.name]
                                        for u in utts)
            first = first or result.trajectories
            rows.append((n, wall, ready, len(failed), same,
                         sum(s.get("met", 0) for s in result.summary),
                         sum(s.get("targets", 0) for s in result.summary)))
            print(f"{n} worker(s): {wall:.1f} s for {len(utts)} utterances "
                  f"({simulated:.2f} s of speech), cluster start and warm-up {ready:.1f} s, "
                  f"{len(failed)} failed, trajectories equal the first count's: {same}",
                  flush=True)
    base = rows[0][1]
    lines = ["| workers | batch wall (s) | utterances per minute | speed-up | "
             "cluster start + warm-up (s) | failed | targets met | same trajectories |",
             "|---|---|---|---|---|---|---|---|"]
    for n, wall, ready, failed, same, met, total in rows:
        lines.append(f"| {n} | {wall:.1f} | {60 * len(utts) / wall:.1f} | "
                     f"{base / wall:.2f} | {ready:.1f} | {failed} | {met} / {total} | "
                     f"{'yes' if same else 'NO'} |")
    table = "\n".join(lines)
    print(table)
    if args.md:
        from solver.app.provenance import commit, command
        Path(args.md).write_text(
            f"Written by `{command('benchmarks/batch_speedup.py', sys.argv[1:])}` at "
            f"{commit()}: {len(utts)} utterances of two {args.window * 1e3:g} ms target "
            f"windows ({simulated:.2f} s of speech in all), FaceFMU at fidelity "
            f"`{args.fidelity}` with LipMotorControl, 5 ms steps, on LocalClusters of "
            "one-thread workers on this machine (2 cores).\n\n" + table + "\n")


if __name__ == "__main__":
    main()
