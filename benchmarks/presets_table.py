"""The table of the fidelity presets: docs/presets.md, from solver.app.fidelity.

    python benchmarks/presets_table.py [--out docs/presets.md]

Writes a markdown table of every preset's fields (solver.app.fidelity.PRESETS) and of the
full-order knobs of the reduced-order fidelity `realtime` (REDUCED), with the command that
made it. Runs nothing: the values are the module's constants.
"""

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):                     # run as a script: the repository root
    sys.path.insert(0, str(ROOT))
from solver.app.fidelity import PRESETS, REDUCED  # noqa: E402

COMMAND = "python benchmarks/presets_table.py"
# field -> (unit, meaning), in table order; a field not listed here is tabulated after them
FIELDS = {
    "level": ("", "mesh level of the generic face"),
    "rows": ("", "brick rows per tissue layer through the thickness (generic face)"),
    "half": ("", "half face (symmetric about the mid-sagittal plane)"),
    "formulation": ("", "element formulation"),
    "integrator": ("", "time integrator: BDF2 or backward Euler"),
    "substep_tol": ("mm", "substep error tolerance, absolute (atol)"),
    "substep_rtol": ("", "substep error tolerance, relative to each displacement"),
    "max_substep": ("s", "largest substep"),
    "newton_rtol": ("", "Newton's residual tolerance, relative to the load scale"),
    "newton_utol": ("mm", "Newton's tolerance on its last update"),
    "lip_penalty": ("N/mm^3", "lip/lip contact penalty"),
}


def cell(value):
    """A table cell: None (a field the fidelity does not set) as the scene's."""
    if value is None:
        return "the scene's"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:g}" if isinstance(value, float) else str(value)


def presets_markdown():
    """The page: one row per field, one column per fidelity."""
    columns = {**{f"`{n}`": v for n, v in PRESETS.items()},
               **{f"`{n}` (full-order knobs)": v for n, v in REDUCED.items()}}
    fields = list(FIELDS) + sorted({f for v in columns.values() for f in v} - set(FIELDS))
    lines = ["# Fidelity presets", "",
             f"Written by `{COMMAND}` from `solver/app/fidelity.py` (PRESETS, REDUCED): the "
             "scene fields each fidelity sets; a field it does not set stays the scene's. "
             "An ANSYS face keeps its own mesh: `level` and `rows` do not apply to it. "
             "`realtime` is the reduced-order model ([realtime.md](realtime.md)); its column "
             "holds the knobs of its full-order model (training snapshots, fallback). What "
             "each preset costs and how far its lip outputs are from the fine face: "
             "[accuracy.md](accuracy.md).", "",
             "| field | unit | " + " | ".join(columns) + " | meaning |",
             "|---|---|" + "---|" * len(columns) + "---|"]
    for f in fields:
        unit, meaning = FIELDS.get(f, ("", ""))
        lines.append(f"| `{f}` | {unit} | "
                     + " | ".join(cell(v.get(f)) for v in columns.values())
                     + f" | {meaning} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "presets.md")
    args = ap.parse_args(argv)
    args.out.write_text(presets_markdown())
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
