"""What each muscle does: lip aperture, protrusion and width for every single muscle at
a = 0.5 and 1 on both anatomies, and pictures of the paper's cases (its Figures 8 to 10).

    python examples/muscle_atlas.py [--out docs] [--level paper] [--no-contact]

Static equilibrium, half face (symmetric activations), activation stiffening on (the
paper's whole-brick rule, effects.stiffening_rule = "intersect", as in its scenes), lip/teeth
contact on (unless --no-contact); no lip/lip contact (static Newton with pressed lips is not
robust: the transient scenes carry it), so an aperture of 0 may mean lips crossing. The reference face is used where
../shared/data/reference-face exists. Writes OUT/muscles.md and OUT/img/atlas_*.png.
"""

import argparse
import os
import time
from pathlib import Path

from solver.anatomy.base import MUSCLE_NAMES
from solver.anatomy.load import load_anatomy
from solver.plot import plot_anatomy
from solver.scene import parse_scene, Scene
from solver.simulation import Simulation
from solver.provenance import commit

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = Path(os.environ.get("FACEFMU_REFERENCE_FACE",
                            ROOT / ".." / "shared" / "data" / "reference-face"))
CASES = {"RIS": {"RIS": 1.0}, "BUC": {"BUC": 1.0}, "OOP": {"OOP": 1.0},
         "OOP + BUC": {"OOP": 1.0, "BUC": 1.0}}
KEYS = ("lip_aperture", "lip_protrusion", "lip_width")


def solve(anatomy, activations, contact):
    scene = parse_scene({"scene": {"analysis": "static"},
                         "muscles": {"driven": sorted(activations)},
                         "effects": {"teeth_contact": contact, "lip_contact": False,
                                     "stiffening_rule": "intersect"}})
    sim = Simulation(scene, loaded_anatomy=anatomy)
    sim.set_activations(activations)
    stats = sim.step(1.0)
    if not stats.converged:
        raise RuntimeError(f"{activations}: {stats.reason}")
    return sim


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs"))
    ap.add_argument("--level", default="paper")
    ap.add_argument("--no-contact", action="store_true")
    args = ap.parse_args(argv)
    out = Path(args.out)
    (out / "img").mkdir(parents=True, exist_ok=True)
    contact = not args.no_contact
    anatomies = {f"generic ({args.level})": load_anatomy("generic", args.level, True)}
    if REFERENCE.is_dir():
        anatomies["reference"] = load_anatomy(REFERENCE, half=True)
    lines = ["# What each muscle does", "",
             f"Made by `python examples/muscle_atlas.py --level {args.level}"
             f"{' --no-contact' if not contact else ''}` at commit {commit()}: static "
             f"equilibrium, half face, muscle calibration `{Scene().calibration}` "
             "(solver/muscles.py), "
             f"stiffening on (the paper's whole-brick rule), lip/teeth contact {'on' if contact else 'off'}, no lip/lip contact "
             "(an aperture of 0 may mean crossing lips). Lip measures in mm "
             "(change from rest for aperture and width; protrusion is the forward "
             "displacement).", ""]
    t0 = time.perf_counter()
    for name, anatomy in anatomies.items():
        rest = solve(anatomy, {"OOP": 0.0}, contact).outputs()
        lines += [f"## {name}", "",
                  f"At rest: aperture {rest['lip_aperture']:.2f} mm, width "
                  f"{rest['lip_width']:.2f} mm.", "",
                  "| muscle | a | d aperture | protrusion | d width |", "|---|---|---|---|---|"]
        for m in MUSCLE_NAMES:
            for a in (0.5, 1.0):
                o = solve(anatomy, {m: a}, contact).outputs()
                lines.append(f"| {m} | {a:g} | {o['lip_aperture'] - rest['lip_aperture']:+.2f} | "
                             f"{o['lip_protrusion']:+.2f} | {o['lip_width'] - rest['lip_width']:+.2f} |")
            print(f"{name}: {m} done ({time.perf_counter() - t0:.0f} s)", flush=True)
        lines += ["", "| case | aperture | protrusion | width | picture |", "|---|---|---|---|---|"]
        for case, act in CASES.items():
            sim = solve(anatomy, act, contact)
            o = sim.outputs()
            tag = f"atlas_{name.split()[0]}_{case.replace(' + ', '_')}.png"
            plot_anatomy(anatomy, out / "img" / tag, displacement=sim.face.u,
                         title=f"{name}: {case} at a = 1")
            lines.append(f"| {case} | {o['lip_aperture']:.2f} | {o['lip_protrusion']:+.2f} | "
                         f"{o['lip_width']:.2f} | ![{case}](img/{tag}) |")
        lines.append("")
    lines += ["## Against the paper", "",
              "RIS widens the mouth and pulls the corners back; OOP protrudes the lips and "
              "narrows the aperture; OOP + BUC protrudes less than OOP alone and closes the "
              "lips further, as in the paper. BUC presses the cheek against the teeth, as the "
              "paper observes (its Figure 9; tests/test_muscle_actions.py checks that the "
              "teeth's contact force on the cheek rises with BUC's activation), but it also "
              "pulls the lips back, compare its rows and pictures with OOP's above, where "
              "the paper reports little lip motion. The published BUC fibres run straight "
              "from beside the mouth corners to the back of the cheek, so their tension "
              "retracts the corners; the paper's BUC cables had a real-constant set of "
              "their own (a cross-section), whose value the published data does not give."]
    (out / "muscles.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'muscles.md'} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
