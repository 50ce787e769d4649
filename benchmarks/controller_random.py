"""The speech controller on random target sequences it was not tuned on, as a batch.

    python benchmarks/controller_random.py [--sequences 50] [--seed 1] [--fidelity fast]
                                           [--workers 2] [--md docs/generated/controller_random.md]

Each sequence is 3 to 5 targets drawn (seeded) from what the identified map says the face
reaches (examples/motor_control/inverse_model.json): a random articulatory intent (each
synergy weight 0 with probability 1/2, else uniform in [0, 1]), a jaw opening uniform in
0..10 deg, a window uniform in 100..250 ms; the target is the map at that intent and jaw
(rounded to 0.1 mm), its aperture and protrusion targeted, its width where a spread or
round weight is above 0.5. The sequences run through FaceFMU and LipMotorControl as a
batch (facefmu.batch, 5 ms steps). Prints the share of targets met, the misses by output
and by what preceded them (the jaw's change and the aperture's change into the target,
the window), and writes them with --md.
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
sys.path.insert(0, str(ROOT / "examples" / "motor_control"))


def sequences(n, seed):
    """n target lists (module docstring)."""
    from lipmc_inverse import NAMES, OUTPUTS, LipMap
    lip_map, _ = LipMap.load(ROOT / "examples" / "motor_control" / "inverse_model.json")
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        seq = []
        for k in range(int(rng.integers(3, 6))):
            w = np.where(rng.random(len(NAMES)) < 0.5, 0.0, rng.random(len(NAMES)))
            jaw = float(rng.uniform(0.0, 10.0))
            y = lip_map(w, jaw)
            targeted = ["lip_aperture", "lip_protrusion"]
            if w[NAMES.index("spread")] > 0.5 or w[NAMES.index("round")] > 0.5:
                targeted.append("lip_width")
            seq.append({"phoneme": f"t{k}", "intent": dict(zip(NAMES, w.tolist())),
                        "jaw_opening": round(jaw, 2),
                        "duration": round(float(rng.uniform(0.1, 0.25)), 3),
                        "targeted": targeted,
                        **{o: round(max(float(v), 0.0) if o == "lip_aperture" else float(v),
                                    1) + 0.0 for o, v in zip(OUTPUTS, y)}})
        out.append(seq)
    return out


def misses(result, utts):
    """[(utterance, target index, output, error mm, window s, jaw change deg, aperture
    change mm)] of every missed target."""
    from facefmu import speech
    out = []
    for u in utts:
        rows = result.trajectories[u.name]
        if not rows:
            continue
        for k, (tg, _, checks) in enumerate(speech.tracking(rows, u.targets)):
            prev = u.targets[k - 1] if k else {"jaw_opening": 0.0, "lip_aperture": 0.4}
            for o, c in checks.items():
                if not c[4]:
                    out.append((u.name, k, o, c[2], tg["duration"],
                                tg["jaw_opening"] - prev["jaw_opening"],
                                tg["lip_aperture"] - prev["lip_aperture"]))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--fidelity", default="fast")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--md", default="")
    args = ap.parse_args(argv)
    from cosim_speech import build_fmus, speech_system
    from facefmu import speech
    from facefmu.batch import Batch, from_targets
    seqs = sequences(args.sequences, args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i, seq in enumerate(seqs):
            p = Path(tmp) / f"seq{i:02d}.json"
            p.write_text(json.dumps(seq))
            paths.append(p)
        face, control = build_fmus(tmp)
        system = speech_system(face, control, 0.005)
        system.initial["face"]["fidelity"] = args.fidelity
        utts = from_targets(paths)
        t0 = time.perf_counter()
        with Batch(system, speech.records(system), n_workers=args.workers) as batch:
            result = batch.run(utts)
        wall = time.perf_counter() - t0
    failed = [s for s in result.summary if not s["ok"]]
    total = sum(len(u.targets) for u in utts)
    miss = misses(result, utts)
    missed_targets = {(m[0], m[1]) for m in miss}
    met = sum(s.get("met", 0) for s in result.summary)
    lines = [f"{len(utts)} sequences, {total} targets, {sum(u.stop for u in utts):.2f} s "
             f"of speech, {wall:.0f} s on {args.workers} workers: {met} targets met "
             f"({100 * met / total:.1f} %), {len(missed_targets)} missed, "
             f"{len(failed)} sequences failed to run.", ""]
    for s in failed:
        lines.append(f"- {s['utterance']} failed: {s['reason']}")
    if miss:
        lines += ["| sequence | target | output | error (mm) | window (s) | jaw change "
                  "into it (deg) | aperture change into it (mm) |",
                  "|---|---|---|---|---|---|---|"]
        lines += [f"| {n} | {k} | {o} | {e:+.2f} | {w:.3f} | {dj:+.1f} | {da:+.1f} |"
                  for n, k, o, e, w, dj, da in miss]
        by_out = {o: sum(m[2] == o for m in miss) for o in speech.OUTPUTS}
        first = {}
        for m in miss:                          # one entry per missed target
            first.setdefault((m[0], m[1]), m)
        big = sum(abs(m[5]) >= 2.5 or abs(m[6]) >= 4.0 for m in first.values())
        short = sum(m[4] < 0.15 for m in first.values())
        lines += ["", "Misses by output: " + ", ".join(f"{o} {c}" for o, c in by_out.items())
                  + f". Of the {len(first)} missed targets, {big} follow a jaw change of at "
                  "least 2.5 deg or an aperture change of at least 4 mm into their window, "
                  f"{short} have windows shorter than 150 ms, and "
                  f"{sum(m[1] == 0 for m in first.values())} are the first target, from "
                  "rest."]
    text = "\n".join(lines)
    print(text)
    if args.md:
        from solver.app.provenance import commit, command
        Path(args.md).write_text(
            f"Written by `{command('benchmarks/controller_random.py', sys.argv[1:])}` at "
            f"{commit()}: FaceFMU at fidelity `{args.fidelity}` with LipMotorControl, 5 ms "
            f"steps, seed {args.seed}.\n\n" + text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
