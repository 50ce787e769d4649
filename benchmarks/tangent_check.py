"""Each term's tangent against central differences of its residual, at a state of the
fast-path gesture.

    python benchmarks/tangent_check.py [--case a|b] [--time S] [--seed N]

Runs benchmarks/fast_path.py's gesture (case a: the reference face, needs
$FACEFMU_REFERENCE_FACE or ../shared/data/reference-face; case b: the generic face at the
paper level, half face) to --time (default 0.13 s), then for every term but inertia and
damping (linear in u) prints

    |(r(u + du) - r(u - du)) / 2 - K(u) du| / |K(u) du|      on the free DOFs

for random du of sizes 1e-3, 1e-4 and 1e-5 mm per DOF. An exact tangent gives errors that
fall as |du|^2 (rounding below about 1e-9); a missing term in the tangent gives an error
that does not fall with |du|; a kink (a contact status changing within du) one that grows
with it. Newton converges linearly at about that error where a term dominates the
residual (docs/dev-notes/fast_path.md: the lip contact's faded penalty).
"""

import argparse
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):                     # run as a script: the repository root
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.fast_path import REFERENCE_FACE, build, warm_up  # noqa: E402
from solver.core.assembly import Assembly  # noqa: E402

SIZES = (1e-3, 1e-4, 1e-5)                         # mm per DOF


def term_errors(system, term, ids, u, rng):
    """[(size, relative error, |K du|)] of one term at u (ndof,)."""
    def run(x, need_k):
        asm = Assembly(system.pattern, need_k)
        term.assemble(system.state(x), asm, ids)
        return asm
    K = system.pattern.matrix(run(u, True).data)
    free = system.free
    out = []
    for size in SIZES:
        du = np.zeros_like(u)
        du[free] = rng.normal(size=len(free)) * size
        diff = (run(u + du, False).residual - run(u - du, False).residual) / 2
        lin = K @ du
        ref = np.linalg.norm(lin[free])
        out.append((size, np.linalg.norm((diff - lin)[free]) / ref if ref else np.nan, ref))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=("a", "b"), default="a")
    ap.add_argument("--time", type=float, default=0.13)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.case == "a" and not REFERENCE_FACE.is_dir():
        print(f"case a needs the reference face at {REFERENCE_FACE}")
        return 1
    warm_up()
    sim = build(args.case, args.time, "new")
    sim.run()
    system = sim.face.model.system()
    u = sim.face.model.u.ravel().copy()
    rng = np.random.default_rng(args.seed)
    print(f"case {args.case}, t = {sim.t:.4g} s: |central difference - K du| / |K du|")
    print("term | " + " | ".join(f"du {s:g} mm" for s in SIZES))
    print("--- | " + " | ".join("---" for _ in SIZES))
    for term, ids in zip(system.terms, system._ids):
        if term.name in ("inertia", "damping"):
            continue
        rows = term_errors(system, term, ids, u, rng)
        print(f"{term.name} | " + " | ".join(
            "-" if not np.isfinite(e) else f"{e:.1e}" for _, e, _ in rows))
    sim.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
