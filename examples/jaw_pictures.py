"""The face at rest and with the jaw open, on both anatomies.

    python examples/jaw_pictures.py [--opening-mm 12] [--out docs/img]

For the generic face and, where its folder is found (../shared/data/reference-face or
$FACEFMU_REFERENCE_FACE), the reference face, both at the `balanced` preset with the
default scene's contact: opens the jaw to the given incisor opening over 50 ms (then
holds it 50 ms), all muscles at rest, and draws the face with its teeth at rest and
open (solver.app.plot), to OUT/jaw_<anatomy>_rest.png and OUT/jaw_<anatomy>_open.png. Prints
the lip aperture at rest and open.
"""

import argparse
import math
from pathlib import Path

from solver.face.jaw import BONWILL_MM
from solver.app.plot import plot_anatomy
from solver.app.simulation import Simulation
from solver.face.anatomy.reference import reference_face_dir

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = reference_face_dir()


def teeth(sim):
    """The teeth surfaces as posed: (vertices, triangles) of the model's teeth terms."""
    return [(t.vertices, t.tris) for t in sim.contact if hasattr(t, "rest_vertices")]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--opening-mm", type=float, default=12.0)
    ap.add_argument("--out", default=str(ROOT / "docs" / "img"))
    args = ap.parse_args(argv)
    theta = 2.0 * math.degrees(math.asin(args.opening_mm / (2.0 * BONWILL_MM)))
    faces = {"generic": {}}
    if (REFERENCE / "newface.node").is_file():
        faces["reference"] = {"anatomy": str(REFERENCE)}
    else:
        print(f"reference face not found in {REFERENCE}: generic face only")
    out = Path(args.out)
    for name, overrides in faces.items():
        sim = Simulation("default", fidelity="balanced", **overrides)
        rest = sim.outputs()["lip_aperture"]
        plot_anatomy(sim.anatomy, out / f"jaw_{name}_rest.png", sim.face.u,
                     title=f"{name} face, jaw closed: lip aperture {rest:.1f} mm",
                     rigid=teeth(sim))
        for k in range(1, 11):
            sim.set_jaw(opening=theta * min(1.0, k / 5))
            stats = sim.step(0.01 * k)
            if not stats.converged:
                raise SystemExit(f"{name}: step to t = {0.01 * k:.2f} s failed: {stats.reason}")
        o = sim.outputs()
        plot_anatomy(sim.anatomy, out / f"jaw_{name}_open.png", sim.face.u,
                     title=f"{name} face, jaw open {theta:.1f} deg ({o['incisor_opening']:.1f} "
                           f"mm at the incisors): lip aperture {o['lip_aperture']:.1f} mm",
                     rigid=teeth(sim))
        print(f"{name}: lip aperture {rest:.2f} mm at rest, {o['lip_aperture']:.2f} mm with "
              f"the jaw open {theta:.2f} deg ({o['incisor_opening']:.2f} mm at the incisors); "
              f"wrote {out / f'jaw_{name}_rest.png'}, {out / f'jaw_{name}_open.png'}")


if __name__ == "__main__":
    main()
