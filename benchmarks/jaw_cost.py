"""What jaw motion adds to a transient step: the speech gesture with the jaw closed and
with the jaw opening and closing.

    python benchmarks/jaw_cost.py [--scene speech] [--fidelity balanced] [--step 0.005]
                                  [--opening 8] [--repeats 2] [--out docs/jaw_cost.md]

Steps the scene's activation schedule at the communication step in this process, three
ways: the jaw left closed (no jaw input: the model as without a jaw), the jaw set to 0 at
every step (the inputs given, the pose unchanged), and the jaw opening to --opening
degrees and closing again over the gesture (1 - cos, one cycle). Each run builds the
model, then only the stepping is timed (best of --repeats). Prints, per run, the wall
time per communication step and per Newton iteration, the substeps and Newton
iterations, and their ratio to the closed jaw's; writes the table with its command,
commit and date to --out ("" writes none). The per-iteration ratio is the jaw's own
overhead (moving the mandible's nodes, the lower teeth and the insertions); the
per-step ratio also holds what the motion changes in the physics (more substeps and
iterations while the lips move).
"""

import argparse
import datetime
import math
import sys
import time
from pathlib import Path

import numpy as np

from solver.app.simulation import Simulation, resolve_scene
from solver.app.provenance import commit as git_commit

ROOT = Path(__file__).resolve().parents[1]


def run(scene, fidelity, step, jaw):
    """(wall s of the stepping, steps, substeps, Newton iterations, lip aperture (k,))
    with jaw: None (no input), or a function t -> opening (deg)."""
    sim = Simulation(scene, fidelity=fidelity)
    n = int(round(sim.scene.duration / step))
    aperture = []
    subs = iters = 0
    t0 = time.perf_counter()
    for k in range(1, n + 1):
        t = k * step
        sim.set_activations(sim.scene.activations(t))
        if jaw is not None:
            sim.set_jaw(jaw(t), 0.0)
        stats = sim.step(t)
        if not stats.converged:
            raise RuntimeError(f"step to t = {t:.4g} s failed: {stats.reason}")
        subs += stats.substeps
        iters += stats.newton_iterations
        aperture.append(sim.outputs()["lip_aperture"])
    return time.perf_counter() - t0, n, subs, iters, np.array(aperture)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="speech")
    ap.add_argument("--fidelity", default="balanced")
    ap.add_argument("--step", type=float, default=0.005)
    ap.add_argument("--opening", type=float, default=8.0)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "docs" / "jaw_cost.md"))
    args = ap.parse_args(argv)
    scene = resolve_scene(args.scene)
    period = scene.duration

    def cycle(t):
        return 0.5 * args.opening * (1.0 - math.cos(2.0 * math.pi * t / period))

    runs = {"jaw closed, no jaw input": None, "jaw inputs at 0": lambda t: 0.0,
            f"jaw 0 -> {args.opening:g} -> 0 deg": cycle}
    rows, base = [], None
    for label, jaw in runs.items():
        best = None
        for _ in range(args.repeats):
            res = run(scene, args.fidelity, args.step, jaw)
            best = res if best is None or res[0] < best[0] else best
        wall, n, subs, iters, aperture = best
        row = {"run": label, "ms_per_step": 1e3 * wall / n, "ms_per_iteration":
               1e3 * wall / iters, "substeps": subs, "newton_iterations": iters,
               "max_aperture_mm": float(aperture.max())}
        base = base or row
        row["step_ratio"] = row["ms_per_step"] / base["ms_per_step"]
        row["iteration_ratio"] = row["ms_per_iteration"] / base["ms_per_iteration"]
        rows.append(row)
        print(", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                        for k, v in row.items()), flush=True)
    keys = ["run", "ms_per_step", "step_ratio", "ms_per_iteration", "iteration_ratio",
            "substeps", "newton_iterations", "max_aperture_mm"]
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        lines.append("| " + " | ".join(f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k])
                                       for k in keys) + " |")
    table = "\n".join(lines)
    print(table)
    if args.out:
        commit = git_commit()
        command = "python benchmarks/jaw_cost.py" + "".join(f" {a}" for a in
                                                            (argv or sys.argv[1:]))
        Path(args.out).write_text(
            f"# What jaw motion adds to a transient step\n\n"
            f"Written by `{command}` at commit {commit} on "
            f"{datetime.date.today().isoformat()}: the `{args.scene}` scene at the "
            f"`{args.fidelity}` preset, {args.step * 1e3:g} ms communication steps, in "
            f"process; best of {args.repeats} runs each.\n\n{table}\n")
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
