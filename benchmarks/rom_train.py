"""Train the realtime (reduced-order) model of a scene, and measure it on held-out gestures.

    python benchmarks/rom_train.py [--scene SCENE] [--runs 26] [--jaw-runs 12]
                                   [--phrase-runs 48] [--phrase-duration 0.2]
                                   [--jaw-phrase-runs 48]
                                   [--duration 0.15] [--energy 3e-4] [--jaw-energy 1e-5]
                                   [--ecsw-tol 0.1] [--max-wall 30]
                                   [--out FILE.npz]
                                   [--scheduler ADDRESS] [--workers 2] [--no-dask]
    python benchmarks/rom_train.py --ship [--workers 2]
    python benchmarks/rom_train.py --accuracy [--scene SCENE] [--model FILE.npz]
                                   [--gestures oop_ris,open,open_round] [--md FILE]
                                   [--integrators backward_euler,bdf2] [--rom-step 0.005]

SCENE: a built-in scene or a TOML file; the default, `speech` (solver/app/scenes/speech.toml),
drives all ten muscles, transient, with lip and teeth contact, on the generic face. The model is trained for the
scene's full-order model at the realtime knobs (solver.app.fidelity.REDUCED: coarse generic
half face, loose tolerances) and cached in the user cache (solver.rom.store; the path is printed), where
`open_simulation(scene, fidelity="realtime")` finds it. Snapshot runs are independent tasks on
a dask LocalCluster (solver.sweep.Sweep, `--workers` one-thread processes) or a
running scheduler; `--no-dask` runs them here. See solver/rom/train.py for the steps.

--ship trains the model that ships with the project (solver/rom/models; solver.rom.store):
the `default` scene's (the same key as `speech`'s), with this script's defaults and no
wall-time limit on a run, so that the same commit gives the same model; its meta records
the command and the commit. tests/test_rom_shipped.py fails when its key is stale.

--accuracy runs the held-out gestures of solver/rom/accuracy.py with the reduced model
(once per integrator: backward Euler at fixed 1 ms substeps against BDF2 at error-
controlled ones, in the same call) and the full-order model and prints max and RMS
errors (mm) in lip aperture and protrusion and the wall time of each (docs/realtime.md has its figures, with the commands that made them).
"""

import argparse
import sys
from pathlib import Path

if __package__ in (None, ""):                     # run as a script: the repository root
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.table import report  # noqa: E402

def load(name):
    """The scene `name` (built-in or TOML file) at the realtime knobs (the full-order
    model the reduced one is trained on)."""
    from solver.app.fidelity import apply_fidelity
    from solver.app.simulation import resolve_scene
    return apply_fidelity(resolve_scene(name).with_overrides(fidelity=""), "realtime")


def train_main(args):
    from solver.app.provenance import command, commit
    from solver.rom.train import train
    if args.ship:
        from solver.rom.store import SHIPPED, model_path, shipped_scenes
        args.scene, args.max_wall, args.budget = shipped_scenes()[0], None, None
        args.out = model_path(load(args.scene), SHIPPED)
    scene = load(args.scene)
    kw = dict(runs=args.runs, duration=args.duration, energy=1.0 - args.energy,
              jaw_energy=1.0 - args.jaw_energy, jaw_runs=args.jaw_runs,
              phrase_runs=args.phrase_runs, phrase_duration=args.phrase_duration,
              jaw_phrase_runs=args.jaw_phrase_runs,
              ecsw_tol=args.ecsw_tol, out=args.out, seed=args.seed,
              max_wall=args.max_wall, budget=args.budget,
              provenance={"scene": args.scene, "revision": commit(),
                          "command": command("benchmarks/rom_train.py")})
    if args.no_dask:
        return train(scene, **kw)
    from solver.sweep import Sweep
    with Sweep(args.scheduler, n_workers=args.workers) as sweep:
        sweep.warmup(scene)
        return train(scene, client=sweep.client, **kw)


def accuracy_main(args):
    from solver.rom.accuracy import GESTURES, compare
    from solver.entry import open_simulation
    from solver.app.simulation import Simulation
    scene = load(args.scene)
    names = args.gestures.split(",") if args.gestures else list(GESTURES)
    rows, full, full_runs = [], None, {}
    for integrator in args.integrators.split(","):
        rom = open_simulation(scene, fidelity="realtime", rom_model=args.model,
                              check_every=args.check_every, integrator=integrator)
        if full is None:
            full = Simulation(rom.scene, loaded_anatomy=rom.anatomy)  # the full model
            m = rom.rom_meta
            print(f"model: {m['basis_size']} modes, {m['bricks_selected']} of "
                  f"{m['bricks_total']} bricks, trained on {m['runs']} runs in "
                  f"{m['train_s']:.0f} s")
        step = args.rom_step
        label = (f"{integrator}, substeps <= {rom.stepper.h_max * 1e3:g} ms"
                 + (f", tol {rom.stepper.tol:g} mm" if rom.stepper.tol else ""))
        for r in compare(rom, full, names, rom_step=step, full_runs=full_runs):
            rows.append({"integrator": label, **r})
        rom.release()
    cols = ["integrator", "gesture", "duration_s", "max_err_aperture_mm",
            "rms_err_aperture_mm", "max_err_protrusion_mm", "rms_err_protrusion_mm",
            "full_range_aperture_mm", "full_range_protrusion_mm", "rom_wall_s", "rom_cpu_s",
            "rom_ms_per_step", "full_wall_s", "full_cpu_s", "rom_rtf", "full_rtf", "rho_max",
            "fell_back"]
    report(rows, cols, args.csv)
    if args.md:
        from solver.app.provenance import command, stamp
        head = (f"Held-out gestures, reduced (caller steps of {args.rom_step * 1e3:g} ms) "
                f"against full order (5 ms), one process, one reduced run per integrator "
                f"and gesture: `{command('benchmarks/rom_train.py')}`, {stamp()}; model: "
                f"{m['basis_size']} modes ({m.get('jaw_modes', 0)} of them from the "
                f"jaw runs), {m['bricks_selected']} of {m['bricks_total']} bricks.\n\n")
        with open(args.md, "w") as fh:          # stamped before the file is emptied
            fh.write(head)
            fh.write("| " + " | ".join(cols) + " |\n|" + "---|" * len(cols) + "\n")
            for r in rows:
                fh.write("| " + " | ".join(f"{r[c]:.3g}" if isinstance(r[c], float)
                                           else str(r[c]) for c in cols) + " |\n")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="speech")
    ap.add_argument("--runs", type=int, default=26, help="snapshot runs")
    ap.add_argument("--duration", type=float, default=0.15, help="s per snapshot run")
    ap.add_argument("--energy", type=float, default=3e-4,
                    help="POD energy left out (basis: captured energy >= 1 - this)")
    ap.add_argument("--jaw-energy", type=float, default=1e-5,
                    help="POD energy left out of the jaw runs' remainder (solver.rom.train)")
    ap.add_argument("--jaw-runs", type=int, default=12, help="snapshot runs moving the jaw")
    ap.add_argument("--phrase-runs", type=int, default=48,
                    help="speech-like snapshot runs (solver.rom.train.random_phrase)")
    ap.add_argument("--phrase-duration", type=float, default=0.2, help="s per phrase run")
    ap.add_argument("--jaw-phrase-runs", type=int, default=48,
                    help="more phrase runs, each moving the jaw (their own seed)")
    ap.add_argument("--ecsw-tol", type=float, default=0.1, help="ECSW relative tolerance")
    ap.add_argument("--seed", type=int, default=1, help="of the random activation patterns")
    ap.add_argument("--budget", type=float, help="s: snapshot runs not finished by then "
                    "are left out (finished runs are cached and reused by the next call)")
    ap.add_argument("--max-wall", type=float, default=30.0,
                    help="s: a snapshot run stops there, keeping its snapshots")
    ap.add_argument("--out", type=Path, help="model file (default: the user cache)")
    ap.add_argument("--scheduler", help="address of a running dask scheduler")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes")
    ap.add_argument("--no-dask", action="store_true", help="snapshot runs in this process")
    ap.add_argument("--ship", action="store_true", help="train the shipped model "
                    "(solver/rom/models) of the default scene, deterministically")
    ap.add_argument("--accuracy", action="store_true", help="held-out gestures, ROM vs full")
    ap.add_argument("--model", type=Path, help="--accuracy: this model file (default: the "
                                               "cached model of the scene)")
    ap.add_argument("--gestures", help="--accuracy: comma-separated gesture names")
    ap.add_argument("--check-every", type=int, default=20,
                    help="--accuracy: substeps between trust checks")
    ap.add_argument("--integrators", default="backward_euler,bdf2",
                    help="--accuracy: the reduced model's integrators, each a row per "
                         "gesture (backward_euler: fixed 1 ms substeps; bdf2: error-"
                         "controlled, up to 5 ms)")
    ap.add_argument("--rom-step", type=float, default=5e-3,
                    help="--accuracy: the reduced model's caller step (s)")
    ap.add_argument("--csv", type=Path, help="--accuracy: write the table as CSV")
    ap.add_argument("--md", type=Path, help="--accuracy: write the table as markdown")
    args = ap.parse_args(argv)
    if args.accuracy:
        accuracy_main(args)
    else:
        train_main(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
