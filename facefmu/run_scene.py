"""`facefmu run [SCENE]`: a standalone run of a built-in scene or a scene file.

Writes OUT/SCENE.csv (the recorded outputs and activations at every output interval),
OUT/SCENE.png (outputs and activations over time) and, with --vtu, one VTU file per
record (displacements and principal strains, for ParaView). The picture needs the
package's `plot` extra, the progress bar (unless --quiet) `sweep`, --vtu `export`: they
are checked before the run.
"""

import csv
from pathlib import Path

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.app.extras import need
from solver.entry import open_simulation
from solver.app.simulation import builtin_scenes


def add_arguments(parser):
    parser.add_argument("scene", nargs="?", default="default",
                        help=f"a built-in scene ({', '.join(builtin_scenes())}) or a scene "
                             "TOML file (default: default, the paper's model for speech)")
    parser.add_argument("--out", default="out", help="output folder (default: out)")
    parser.add_argument("--anatomy", help="override the scene's anatomy ('generic' or a folder)")
    parser.add_argument("--level", help="override the scene's level (generic face: that "
                        "level's own brick rows)")
    parser.add_argument("--full", action="store_true", help="simulate the full face")
    parser.add_argument("--jaw-opening", type=float, metavar="DEG",
                        help="hold the jaw open by DEG degrees (reached over the first "
                             "output interval; replaces the scene's jaw schedules)")
    parser.add_argument("--jaw-protrusion", type=float, metavar="MM",
                        help="hold the jaw protruded by MM mm (likewise)")
    parser.add_argument("--vtu", action="store_true", help="write a VTU frame per record")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args):
    need("matplotlib", "plot", "facefmu run (its PNG)")
    if not args.quiet:
        need("tqdm", "sweep", "facefmu run's progress bar (--quiet: none)")
    if args.vtu:
        need("meshio", "export", "facefmu run --vtu")
    overrides = {k: v for k, v in (("anatomy", args.anatomy), ("level", args.level)) if v}
    if args.level:
        overrides["rows"] = None                # the level's own rows, not a preset's
    if args.full:
        overrides["half"] = False
    sim = open_simulation(args.scene, **overrides)
    held = {k: v for k, v in (("opening", args.jaw_opening),
                              ("protrusion", args.jaw_protrusion)) if v is not None}
    if held:
        sim.scene = hold_jaw(sim.scene, held)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    name = sim.scene.name
    frames = []

    def on_record(s, row):
        if args.vtu:
            from solver.app.io.export import export_anatomy
            path = out / f"{name}_{len(frames):04d}.vtu"
            export_anatomy(s.anatomy, path, displacement=s.face.u)
            frames.append(path)

    print(f"scene {name}: {sim.scene.description}")
    print(f"  terms: {', '.join(sim.term_names)}")
    for warning in sim.scene.contact_warnings():
        print(f"  warning: {warning}")
    rows = sim.run(progress=not args.quiet, on_record=on_record)
    with open(out / f"{name}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot_run(rows, out / f"{name}.png", name)
    last = rows[-1]
    print("  at t = {:.4g} s: ".format(last["time"]) + ", ".join(
        f"{k} {v:.3f}" for k, v in last.items() if k in sim.scene.record and isinstance(v, float)))
    print(f"wrote {out / f'{name}.csv'}, {out / f'{name}.png'}"
          + (f" and {len(frames)} VTU frames" if frames else ""))
    return 0


def hold_jaw(scene, held):
    """The scene with its jaw schedules replaced by ramps to the held values (dict
    'opening' | 'protrusion' -> value) over its first output interval."""
    from solver.app.scene import parse_scene_schedule
    keep = tuple(s for s in scene.schedules if not s.muscle.startswith("jaw_"))
    ramps = tuple(parse_scene_schedule({"jaw": k, "kind": "ramp", "start": 0.0,
                                        "end": scene.interval, "to": v}, scene)
                  for k, v in held.items())
    return scene.with_overrides(schedules=keep + ramps)


def plot_run(rows, path, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = [r["time"] for r in rows]
    lips = [k for k in ("lip_aperture", "lip_protrusion", "lip_width") if k in rows[0]]
    fig, ax = plt.subplots(len(lips) + 1, 1, figsize=(8, 2.2 * (len(lips) + 1)), sharex=True)
    for a, k in zip(ax, lips):
        a.plot(t, [r[k] for r in rows], "o-", ms=3)
        a.set_ylabel(f"{k.replace('lip_', '')} (mm)")
        a.grid(alpha=0.3)
    for m in MUSCLE_NAMES:
        if m in rows[0] and max(r[m] for r in rows) > 0:
            ax[-1].plot(t, [r[m] for r in rows], label=m)
    ax[-1].set_ylabel("activation")
    ax[-1].set_xlabel("time (s)")
    if ax[-1].get_lines():
        ax[-1].legend(fontsize=8, ncol=5)
    ax[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
