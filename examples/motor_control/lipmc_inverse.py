"""The face's static lip map and its inverse, as the motor-control FMU uses them.

Muscle synergies: four activation patterns, each a weight w_k in [0, 1], mixed into the
ten activations as a = clip(sum_k w_k s_k, 0, 1):

    open    LLSAN + DLI    raise the upper lip, lower the lower lip
    round   OOP            protrude and narrow the lips (orbicularis oris peripheralis)
    spread  RIS + ZYG      widen the mouth, pull the corners back
    close   OOM + MENT     press the lips together (orbicularis oris marginalis, mentalis)

The jaw: its opening j (degrees, the face's jaw_opening input) is not a synergy but a
command of its own, given by the target (the jaw opens the mouth for an open vowel; the
lips shape it); the map takes it as a fifth input s = j / JAW_SCALE.

Forward model: the lip outputs y = (aperture, protrusion, width) in mm that the face holds
at steady state under the weights w (shape (4,)) and the jaw opening j, from a quadratic
polynomial g = C phi(x), x = (w, s), phi(x) = (1, x_i, x_i x_j for i <= j) (21 features),
C of shape (3, 21), fitted to the face's own responses (identify.py). The aperture stops at 0 where the lips
touch: its g is a signed gap, fitted as censored data (closed samples only ask g <= 0),
and y = s log(1 + exp(g / s)), a max(g, 0) smoothed over s = 0.1 mm.

Inverse: for a desired output r (mm), output weights q (1/mm, 0 for an output that is
not targeted) and the jaw opening j, the weights minimizing

    J(w) = sum_i q_i^2 (f_i(w) - r_i)^2 + lam^2 |w - w_ref|^2,  0 <= w <= 1,

by projected Gauss-Newton (Levenberg-damped, a few iterations from a warm start). lam
keeps the effort small where the outputs do not decide (four synergies, three outputs).
Only numpy: this file ships inside the controller FMU.
"""

import json

import numpy as np

SYNERGIES = {
    "open": {"LLSAN": 1.0, "DLI": 1.0},
    "round": {"OOP": 1.0},
    "spread": {"RIS": 1.0, "ZYG": 1.0},
    "close": {"OOM": 1.0, "MENT": 1.0},
}
NAMES = tuple(SYNERGIES)
OUTPUTS = ("lip_aperture", "lip_protrusion", "lip_width")
MUSCLES = ("LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM")
JAW_SCALE = 10.0                    # deg: the jaw input of the map is s = j / JAW_SCALE
_N = len(NAMES) + 1                 # the map's inputs: the synergy weights and s
_PAIRS = [(i, j) for i in range(_N) for j in range(i, _N)]


def activations(w):
    """dict muscle -> activation in [0, 1] of the synergy weights w (shape (4,))."""
    a = dict.fromkeys(MUSCLES, 0.0)
    for wk, name in zip(w, NAMES):
        for m, s in SYNERGIES[name].items():
            a[m] += float(wk) * s
    return {m: min(max(v, 0.0), 1.0) for m, v in a.items()}


def inputs(w, jaw=0.0):
    """x = (w, jaw / JAW_SCALE): shape (..., 5) for w of shape (..., 4), jaw (deg) a
    scalar or of shape (...)."""
    w = np.asarray(w, dtype=float)
    s = np.broadcast_to(np.asarray(jaw, dtype=float) / JAW_SCALE, w.shape[:-1])
    return np.concatenate([w, s[..., None]], axis=-1)


def features(x):
    """phi(x): shape (..., 21) for x of shape (..., 5) (inputs)."""
    x = np.asarray(x, dtype=float)
    quad = [x[..., i] * x[..., j] for i, j in _PAIRS]
    return np.concatenate([np.ones(x.shape[:-1] + (1,)), x, np.stack(quad, axis=-1)], axis=-1)


def feature_jacobian(x):
    """d phi / d w (the synergy weights, not the jaw): shape (21, 4)."""
    n = len(NAMES)
    d = np.zeros((1 + _N + len(_PAIRS), _N))
    d[1:1 + _N] = np.eye(_N)
    for k, (i, j) in enumerate(_PAIRS):
        d[1 + _N + k, i] += x[j]
        d[1 + _N + k, j] += x[i]
    return d[:, :n]


FLOORED = (True, False, False)      # outputs that stop at 0 (the aperture)
SOFTNESS = 0.1                      # mm


class LipMap:
    """y(w) from g = C phi(w) and its bounded inverse. coef: shape (3, 15)."""

    def __init__(self, coef, floored=FLOORED, softness=SOFTNESS):
        self.coef = np.asarray(coef, dtype=float)
        self.floored = np.asarray(floored, dtype=bool)
        self.s = float(softness)

    @classmethod
    def load(cls, path):
        with open(path) as fh:
            data = json.load(fh)
        return cls(data["coef"], data["floored"], data["softness"]), data

    def __call__(self, w, jaw=0.0):
        """y (mm, shape (3,)) at the weights w (shape (4,)) and jaw opening jaw (deg)."""
        g = self.coef @ features(inputs(w, jaw))
        x = g[self.floored] / self.s
        g[self.floored] = self.s * (np.maximum(x, 0.0) + np.log1p(np.exp(-np.abs(x))))
        return g

    def jacobian(self, w, jaw=0.0):
        """dy/dw: shape (3, 4)."""
        x = inputs(w, jaw)
        J = self.coef @ feature_jacobian(x)
        g = self.coef[self.floored] @ features(x)
        J[self.floored] *= (1.0 / (1.0 + np.exp(-g / self.s)))[:, None]
        return J

    def inverse(self, r, q, w0=None, lam=0.05, w_ref=None, iterations=30, jaw=0.0):
        """Weights w (shape (4,)) in [0, 1] minimizing J above for the desired outputs r
        (mm, shape (3,)) with output weights q (1/mm, shape (3,)) at the jaw opening jaw
        (deg); w0: warm start."""
        n = len(NAMES)
        w = np.full(n, 0.3) if w0 is None else np.clip(np.asarray(w0, dtype=float), 0, 1)
        w_ref = np.zeros(n) if w_ref is None else np.asarray(w_ref, dtype=float)
        q = np.asarray(q, dtype=float)
        r = np.asarray(r, dtype=float)

        def cost(w):
            return float(np.sum((q * (self(w, jaw) - r)) ** 2)
                         + lam ** 2 * np.sum((w - w_ref) ** 2))

        c, mu = cost(w), 1e-3
        for _ in range(iterations):
            J = q[:, None] * self.jacobian(w, jaw)
            g = J.T @ (q * (self(w, jaw) - r)) + lam ** 2 * (w - w_ref)
            H = J.T @ J + lam ** 2 * np.eye(n)
            # free set: weights not held at a bound by the gradient
            free = ~(((w <= 0.0) & (g > 0)) | ((w >= 1.0) & (g < 0)))
            if not free.any():
                break
            step = np.zeros(n)
            Hf = H[np.ix_(free, free)] + mu * np.eye(free.sum())
            step[free] = -np.linalg.solve(Hf, g[free])
            trial = np.clip(w + step, 0.0, 1.0)
            ct = cost(trial)
            if ct < c:
                done = c - ct < 1e-12
                w, c, mu = trial, ct, max(mu / 3.0, 1e-6)
                if done:
                    break
            else:
                mu *= 10.0
                if mu > 1e6:
                    break
        return w
