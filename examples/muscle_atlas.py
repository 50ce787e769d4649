"""What each muscle does: lip aperture, protrusion and width for every single muscle at
a = 0.5 and 1 on both anatomies, the speech synergies' range beside published speech lip
targets, and pictures of the paper's cases (its Figures 8 to 10).

    python examples/muscle_atlas.py [--out docs] [--level paper] [--no-contact]

Static equilibrium, half face (symmetric activations), the default muscle calibration,
activation stiffening on (the paper's whole-brick rule, effects.stiffening_rule =
"intersect", as in its scenes), lip/lip and lip/teeth contact on (off with --no-contact).
Where load-stepped Newton stops at a limit point (a folding lip) the damped relaxation
finds the equilibrium (solver.core.transient.relax); a state where that fails too is
printed with its reason and tabulated as nan. The reference face is used where
../shared/data/reference-face exists. Writes OUT/muscles.md and OUT/img/atlas_*.png.

Speech range: the four synergies of the motor-control example
(examples/motor_control/lipmc_inverse.SYNERGIES) at full weight, the open vowel's intent
with the jaw open, and the range over every state of the page, beside lip targets of
VocalTractLab's JD3 speaker (Birkholz; model parameters, not measurements): protrusion
about 10 mm for /u/, 7 mm for /o/, under 1 mm for /a/ and /i/; aperture about 3.4 mm for
/u/, 2.6 mm for /o/, 9.9 mm for /a/, 9.3 mm for /i/; 0 mm for bilabial stops.
"""

import argparse
import time
from pathlib import Path

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.face.anatomy.load import load_anatomy
from solver.app.plot import plot_anatomy
from solver.app.scene import parse_scene, Scene
from solver.app.simulation import Simulation
from solver.app.provenance import commit
from solver.face.anatomy.reference import reference_face_dir

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = reference_face_dir()
CASES = {"RIS": {"RIS": 1.0}, "BUC": {"BUC": 1.0}, "OOP": {"OOP": 1.0},
         "OOP + BUC": {"OOP": 1.0, "BUC": 1.0}}
# the motor-control example's synergies (examples/motor_control/lipmc_inverse.py), and its
# open vowel's intent with the jaw: (activations, jaw opening deg)
SPEECH = {"open (LLSAN + DLI)": ({"LLSAN": 1.0, "DLI": 1.0}, 0.0),
          "round (OOP)": ({"OOP": 1.0}, 0.0),
          "spread (RIS + ZYG)": ({"RIS": 1.0, "ZYG": 1.0}, 0.0),
          "close (OOM + MENT)": ({"OOM": 1.0, "MENT": 1.0}, 0.0),
          "open 0.5, jaw 8 deg (/a/)": ({"LLSAN": 0.5, "DLI": 0.5}, 8.0)}
PUBLISHED = ("| VocalTractLab JD3 (model targets) | 0 (stops) to 9.9 (/a/) | "
             "under 1 (/a/, /i/) to 10 (/u/) | - |")
KEYS = ("lip_aperture", "lip_protrusion", "lip_width")


def solve(anatomy, activations, contact, jaw=0.0):
    scene = parse_scene({"scene": {"analysis": "static"},
                         "muscles": {"driven": sorted(activations)},
                         "effects": {"teeth_contact": contact, "lip_contact": contact,
                                     "stiffening_rule": "intersect"}})
    sim = Simulation(scene, loaded_anatomy=anatomy)
    sim.set_activations(activations)
    if jaw:
        sim.set_jaw(opening=jaw)
    stats = sim.step(1.0)
    if not stats.converged:
        print(f"no equilibrium for {activations}, jaw {jaw} deg: {stats.reason}", flush=True)
        return None
    return sim


def outputs(sim):
    """The lip outputs of a solved state; NaN where the solve found no equilibrium."""
    return {k: float("nan") for k in KEYS} if sim is None else sim.outputs()


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
             "(solver/face/muscles.py), "
             f"stiffening on (the paper's whole-brick rule), lip/lip and lip/teeth contact "
             f"{'on' if contact else 'off'}. Lip measures in mm "
             "(change from rest for aperture and width; protrusion is the forward "
             "displacement).", ""]
    t0 = time.perf_counter()
    for name, anatomy in anatomies.items():
        rest = solve(anatomy, {"OOP": 0.0}, contact).outputs()    # the face at rest
        lines += [f"## {name}", "",
                  f"At rest: aperture {rest['lip_aperture']:.2f} mm, width "
                  f"{rest['lip_width']:.2f} mm.", "",
                  "| muscle | a | d aperture | protrusion | d width |", "|---|---|---|---|---|"]
        states = [rest]
        for m in MUSCLE_NAMES:
            for a in (0.5, 1.0):
                o = outputs(solve(anatomy, {m: a}, contact))
                states.append(o)
                lines.append(f"| {m} | {a:g} | {o['lip_aperture'] - rest['lip_aperture']:+.2f} | "
                             f"{o['lip_protrusion']:+.2f} | {o['lip_width'] - rest['lip_width']:+.2f} |")
            print(f"{name}: {m} done ({time.perf_counter() - t0:.0f} s)", flush=True)
        lines += ["", "| case | aperture | protrusion | width | picture |", "|---|---|---|---|---|"]
        for case, act in CASES.items():
            sim = solve(anatomy, act, contact)
            o = outputs(sim)
            tag = f"atlas_{name.split()[0]}_{case.replace(' + ', '_')}.png"
            if sim is not None:
                plot_anatomy(anatomy, out / "img" / tag, displacement=sim.face.u,
                             title=f"{name}: {case} at a = 1")
            picture = f"![{case}](img/{tag})" if sim is not None else "no equilibrium"
            lines.append(f"| {case} | {o['lip_aperture']:.2f} | {o['lip_protrusion']:+.2f} | "
                         f"{o['lip_width']:.2f} | {picture} |")
            print(f"{name}: {case} done ({time.perf_counter() - t0:.0f} s)", flush=True)
        lines += ["", f"### Speech range ({name})", "",
                  "| state | aperture | protrusion | width |", "|---|---|---|---|"]
        for case, (act, jaw) in SPEECH.items():
            o = outputs(solve(anatomy, act, contact, jaw))
            states.append(o)
            lines.append(f"| {case} | {o['lip_aperture']:.2f} | {o['lip_protrusion']:+.2f} | "
                         f"{o['lip_width']:.2f} |")
            print(f"{name}: {case} done ({time.perf_counter() - t0:.0f} s)", flush=True)
        solved = [o for o in states if o[KEYS[0]] == o[KEYS[0]]]
        rng = {k: (min(o[k] for o in solved), max(o[k] for o in solved)) for k in KEYS}
        lines += ["| range over this page's states | " + " | ".join(
            f"{lo:+.2f} to {hi:+.2f}" if k == "lip_protrusion" else f"{lo:.2f} to {hi:.2f}"
            for k, (lo, hi) in rng.items()) + " |", PUBLISHED, ""]
        print(f"{name}: speech range done ({time.perf_counter() - t0:.0f} s)", flush=True)
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
