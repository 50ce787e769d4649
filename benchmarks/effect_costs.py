"""What each effect costs in time and what leaving it out changes in the lip outputs.

    python benchmarks/effect_costs.py [--scene bilabial_p] [--level coarse] [--csv out.csv]

Runs the scene with every effect it calls for, then once without each effect in turn.
Per effect: its share of the assembly time in the full run (per-term timers), the wall
time of the run without it, and the largest change over time in lip aperture and
protrusion (mm) against the full run.
"""

import argparse
import time

from solver.app.simulation import Simulation, resolve_scene
from table import report

SWITCHES = {"inertia": "inertia", "damping": "damping", "stiffening": "stiffening",
            "lip_contact": "lip_contact", "teeth_contact": "teeth_contact",
            "gravity": "gravity"}


def run(scene):
    sim = Simulation(scene)
    t0 = time.perf_counter()
    rows = sim.run()
    wall = time.perf_counter() - t0
    seconds = sim.face.model.system().term_seconds
    return wall, rows, seconds


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="bilabial_p")
    ap.add_argument("--level", default="coarse")
    ap.add_argument("--csv")
    args = ap.parse_args(argv)
    scene = resolve_scene(args.scene).with_overrides(level=args.level)
    wall, ref, seconds = run(scene)
    total = sum(seconds.values())
    print(f"scene {scene.name} ({scene.level}): {wall:.2f} s wall with all effects; "
          f"assembly {total:.2f} s")
    table = []
    for effect in scene.effects:
        spent = sum(v for k, v in seconds.items() if k == effect or k.endswith(f"_{effect}"))
        row = {"effect": effect, "share_of_assembly": spent / total}
        flag = SWITCHES.get(effect)
        if flag is not None:
            off = scene.with_overrides(**{flag: "none" if flag == "gravity" else False})
            w, rows, _ = run(off)
            row["wall_without_s"] = w
            row["d_aperture_mm"] = max(abs(a["lip_aperture"] - b["lip_aperture"])
                                       for a, b in zip(ref, rows))
            row["d_protrusion_mm"] = max(abs(a["lip_protrusion"] - b["lip_protrusion"])
                                         for a, b in zip(ref, rows))
        table.append(row)
    report(table, ["effect", "share_of_assembly", "wall_without_s", "d_aperture_mm",
                   "d_protrusion_mm"], args.csv)


if __name__ == "__main__":
    main()
