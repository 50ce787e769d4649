"""Identify the face's static lip map from FaceFMU's own responses, and choose speech
targets that the face can reach.

    python examples/motor_control/identify.py [--samples 96] [--hold 0.3] [--jobs 2]
    python examples/motor_control/identify.py --refit      # fit the stored samples again
    python examples/motor_control/identify.py --check 3    # are they still the face's?

Each sample holds one set of synergy weights w (lipmc_inverse.SYNERGIES) and one jaw
opening j from rest for `hold` seconds through FaceFMU (fmpy, 10 ms communication steps,
the jaw ramped to j over its first JAW_RAMP seconds) and records the lip aperture,
protrusion and width at the end. The samples run as a batch of open-loop utterances on
dask workers (facefmu.batch: each worker's FMU is restored to its rest state between
samples). The
samples are x = (w, j / JAW_SCALE) in [0, 1]^5: its 32 corners, its centre, and a seeded
Latin hypercube for the rest. A polynomial in x (lipmc_inverse.features) is fitted by
least squares; its leave-one-out errors are printed and stored.

The face's time constant (for the controller's forward model of the response) is fitted
to the same step responses, recorded every 10 ms.

Targets: each phoneme is an articulatory intent (synergy weights and a jaw opening,
PHONEMES below); its target is what the fitted map gives for that intent, rounded to
0.1 mm, with the jaw opening as the target's command. So every target is one the face
reaches at steady state, by the identified model. Jaw openings: 8 deg for /a/ (12 mm at
the incisors, an open vowel), 4 deg for /o/, 2 deg for /i/, 1 deg for /u/ and 0.5 deg
for /p/.

Writes examples/motor_control/inverse_model.json (the map, its fit, the samples, the
targets, and the command, face parameters, commit and date that produced it), which the
controller FMU carries.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
from lipmc_inverse import (FLOORED, JAW_SCALE, NAMES, OUTPUTS, SOFTNESS,  # noqa: E402
                           LipMap, activations, features)

DATA = HERE / "inverse_model.json"
CHECK = 0.05        # mm: the largest change of a stored response that --check accepts
STEP = 0.01
# The face the map is identified on: the FMU's parameters (the main job's face).
FACE = {"scene": "default", "fidelity": "fast"}

JAW_RAMP = 0.05     # s: a sample's jaw reaches its opening over this time
# phoneme: (synergy intent (open, round, spread, close), jaw opening deg, duration s,
# targeted outputs); durations: 100-250 ms per segment; widths are targeted where they
# mark the vowel
PHONEMES = (
    ("a", (0.5, 0.0, 0.0, 0.0), 8.0, 0.20, ("lip_aperture", "lip_protrusion")),
    ("u", (0.0, 0.9, 0.0, 0.3), 1.0, 0.20, ("lip_aperture", "lip_protrusion", "lip_width")),
    ("i", (0.4, 0.0, 0.8, 0.0), 2.0, 0.20, ("lip_aperture", "lip_protrusion", "lip_width")),
    ("p", (0.0, 0.3, 0.0, 1.0), 0.5, 0.15, ("lip_aperture", "lip_protrusion")),
    ("o", (0.3, 0.6, 0.0, 0.0), 4.0, 0.20, ("lip_aperture", "lip_protrusion")),
)


def design(n, seed=7):
    """Sample inputs x = (w, jaw / JAW_SCALE), shape (n, 5): the corners, the centre, then
    a Latin hypercube."""
    d = len(NAMES) + 1
    corners = np.array([[(k >> b) & 1 for b in range(d)] for k in range(2 ** d)], dtype=float)
    pts = [corners, np.full((1, d), 0.5)]
    rest = n - len(corners) - 1
    if rest > 0:
        rng = np.random.default_rng(seed)
        lhs = (np.stack([rng.permutation(rest) for _ in range(d)], axis=1)
               + rng.random((rest, d))) / rest
        pts.append(lhs)
    return np.vstack(pts)[:n]


def build_face(dest):
    subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", str(dest)],
                   check=True, stdout=subprocess.DEVNULL)
    return Path(dest) / "FaceFMU.fmu"


def sample_utterances(samples, hold):
    """One facefmu.batch.Utterance per sample x (design): its activations held, its jaw
    opening ramped over JAW_RAMP, for `hold` seconds at STEP communication steps."""
    from facefmu.batch import Utterance
    steps = int(round(hold / STEP))
    out = []
    for i, x in enumerate(samples):
        inputs = {f"face.{m}": a for m, a in activations(x[:len(NAMES)]).items()}
        inputs["face.jaw_opening"] = [x[len(NAMES)] * JAW_SCALE
                                      * min(1.0, (k + 1) * STEP / JAW_RAMP)
                                      for k in range(steps)]
        out.append(Utterance(f"sample{i}", hold, inputs=inputs))
    return out


def respond(fmu_path, samples, hold, jobs=2):
    """The lip outputs every STEP of each hold (shape (len(samples), hold / STEP, 3)) of
    the inputs samples (n, 5) (design): a batch of open-loop utterances of FaceFMU alone
    on `jobs` dask workers (facefmu.batch; each worker's FMU instance is restored to its
    rest state between samples). SystemExit naming the first sample that failed."""
    from facefmu.batch import Batch
    from facefmu.cosim import System
    system = System({"face": fmu_path}, initial={"face": dict(FACE)}, step=STEP)
    with Batch(system, [f"face.{o}" for o in OUTPUTS], n_workers=jobs) as batch:
        result = batch.run(sample_utterances(samples, hold))
    for x, s in zip(samples, result.summary):
        if not s["ok"]:
            raise SystemExit(f"sample {np.round(x, 3).tolist()} (activations, jaw) "
                             f"failed: {s['reason']}")
    return np.array([[[r[o] for o in OUTPUTS] for r in result.trajectories[s["utterance"]]]
                     for s in result.summary])


def fit_output(Phi, y, floored):
    """Coefficients (15,) of one output: least squares; for a floored output, censored
    least squares (samples at the floor count only where the fit is above it), by
    active-set iteration."""
    use = np.ones(len(y), dtype=bool)
    if floored:
        closed = y <= 1e-9
        use = ~closed
    for _ in range(50):
        c = np.linalg.lstsq(Phi[use], y[use], rcond=None)[0]
        if not floored:
            return c
        new = ~closed | (Phi @ c > 0.0)
        if np.array_equal(new, use):
            break
        use = new
    return c


def fit(X, Y):
    """Coefficients (3, 21), and the leave-one-out errors (n, 3) of y(x) in mm, for the
    sample inputs X (n, 5) (design)."""
    Phi = features(X)
    coef = np.array([fit_output(Phi, Y[:, k], f) for k, f in enumerate(FLOORED)])
    loo = np.zeros_like(Y)
    n = len(NAMES)
    for i in range(len(X)):
        keep = np.arange(len(X)) != i
        c = np.array([fit_output(Phi[keep], Y[keep, k], f) for k, f in enumerate(FLOORED)])
        loo[i] = LipMap(c)(X[i, :n], X[i, n] * JAW_SCALE) - Y[i]
    return coef, loo


def time_constant(T, rest):
    """The face's time constant tau (s): the first-order response
    y(t) = y_end + (rest - y_end) exp(-t / tau) fitted by least squares (a scan of tau)
    over the step responses T (shape (n, steps, 3)) from the rest outputs `rest`
    (shape (3,)), over the outputs that change by more than 0.5 mm."""
    t = STEP * np.arange(1, T.shape[1] + 1)
    end = T[:, -1, :]
    change = end - rest
    take = (np.abs(change) > 0.5)[:, None, :]
    taus = np.linspace(0.005, 0.2, 196)
    cost = [np.sum(take * (T - (end[:, None] - change[:, None]
                                * np.exp(-t / tau)[None, :, None])) ** 2) for tau in taus]
    return float(taus[int(np.argmin(cost))])


def commit():
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def check(path, n):
    """Exit status 1 if the first n stored samples' end outputs moved by more than CHECK."""
    old = json.loads(path.read_text())
    W = np.array(old["samples"]["inputs"])[:n]
    Y = np.array(old["samples"]["trajectories"])[:n, -1]
    with tempfile.TemporaryDirectory() as tmp:
        now = respond(build_face(tmp), W, old["provenance"]["hold"])[:, -1]
    diff = np.abs(now - Y).max()
    print(f"{n} stored samples against today's FaceFMU: largest change {diff:.4f} mm")
    return 0 if diff <= CHECK else 1


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=96)
    ap.add_argument("--hold", type=float, default=0.3, help="s held per sample")
    ap.add_argument("--jobs", type=int, default=2, help="dask workers (facefmu.batch)")
    ap.add_argument("--out", default=str(DATA))
    ap.add_argument("--refit", action="store_true", help="fit the samples stored in --out "
                    "again (new targets or model) without running the face")
    ap.add_argument("--check", type=int, metavar="N", help="run the first N stored samples "
                    "through today's FaceFMU and exit 1 if an output moved by more than "
                    f"{CHECK} mm (the stored map is stale: identify again)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.check:
        return check(Path(args.out), args.check)
    if args.refit:
        old = json.loads(Path(args.out).read_text())
        W, T = np.array(old["samples"]["inputs"]), np.array(old["samples"]["trajectories"])
        Y = T[:, -1]
        args.hold, command = old["provenance"]["hold"], old["provenance"]["command"]
    else:
        W = design(args.samples)
        command = "python examples/motor_control/identify.py " + " ".join(
            argv if argv is not None else sys.argv[1:])
        with tempfile.TemporaryDirectory() as tmp:
            T = respond(build_face(tmp), W, args.hold, args.jobs)
        Y = T[:, -1]
    wall = time.perf_counter() - t0
    coef, loo = fit(W, Y)
    tau = time_constant(T, T[0, -1])          # sample 0: no activation, the rest state
    lip_map = LipMap(coef)
    n = len(NAMES)
    resid = Y - np.array([lip_map(x[:n], x[n] * JAW_SCALE) for x in W])
    rms = np.sqrt(np.mean(resid ** 2, axis=0))
    loo_rms = np.sqrt(np.mean(loo ** 2, axis=0))
    print(f"{len(W)} responses of {args.hold} s through FaceFMU"
          + ("(stored)" if args.refit else f" in {wall:.0f} s"))
    print("output           range (mm)        fit rms   leave-one-out rms / max (mm)")
    for k, name in enumerate(OUTPUTS):
        print(f"{name:15s} {Y[:, k].min():7.2f} .. {Y[:, k].max():6.2f}   {rms[k]:7.3f}"
              f"   {loo_rms[k]:7.3f} / {np.abs(loo[:, k]).max():.3f}")
    print(f"time constant of the face's step responses: {tau * 1e3:.0f} ms")
    targets = []
    for name, intent, jaw, duration, targeted in PHONEMES:
        y = lip_map(np.array(intent), jaw)
        targets.append({"phoneme": name, "intent": dict(zip(NAMES, intent)),
                        "jaw_opening": jaw, "duration": duration, "targeted": list(targeted),
                        **{o: round(max(float(v), 0.0) if f else float(v), 1) + 0.0
                           for o, v, f in zip(OUTPUTS, y, FLOORED)}})
        print(f"  /{name}/ intent {intent}, jaw {jaw:g} deg: " + ", ".join(
            f"{o} {v:.2f}" for o, v in zip(OUTPUTS, y)))
    data = {
        "about": "Static lip map of FaceFMU and speech targets (examples/motor_control/"
                 "identify.py; lipmc_inverse.py explains the model)",
        "synergies": list(NAMES), "jaw_scale": JAW_SCALE, "outputs": list(OUTPUTS),
        "coef": coef.tolist(),
        "floored": list(FLOORED), "softness": SOFTNESS,
        "fit": {"rms": rms.tolist(), "loo_rms": loo_rms.tolist(),
                "loo_max": np.abs(loo).max(axis=0).tolist()},
        "tau_face": tau,
        "samples": {"inputs": W.tolist(), "trajectories": np.round(T, 5).tolist()},
        "targets": targets,
        "provenance": old["provenance"] | {"fitted_at_commit": commit()} if args.refit else
        {"command": command.strip(), "face": FACE, "hold": args.hold, "step": STEP,
         "commit": commit(), "date": datetime.now(timezone.utc).strftime("%Y-%m-%d")},
    }
    Path(args.out).write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    sys.exit(main() or 0)
