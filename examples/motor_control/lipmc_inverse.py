"""The face's static lip map and its inverse, as the motor-control FMU uses them.

Muscle synergies: four activation patterns, each a weight w_k in [0, 1], mixed into the
ten activations as a = clip(sum_k w_k s_k, 0, 1):

    open    LLSAN + DLI    raise the upper lip, lower the lower lip
    round   OOP            protrude and narrow the lips (orbicularis oris peripheralis)
    spread  RIS + ZYG      widen the mouth, pull the corners back
    close   OOM + MENT     press the lips together (orbicularis oris marginalis, mentalis)

Forward model: the lip outputs y = (aperture, protrusion, width) in mm that the face holds
at steady state under the weights w (shape (4,)), from a quadratic polynomial
g = C phi(w), phi(w) = (1, w_i, w_i w_j for i <= j) (15 features), C of shape (3, 15),
fitted to the face's own responses (identify.py). The aperture stops at 0 where the lips
touch: its g is a signed gap, fitted as censored data (closed samples only ask g <= 0),
and y = s log(1 + exp(g / s)), a max(g, 0) smoothed over s = 0.1 mm.

Inverse: for a desired output r (mm) and output weights q (1/mm, 0 for an output that is
not targeted), the weights minimizing

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
_PAIRS = [(i, j) for i in range(len(NAMES)) for j in range(i, len(NAMES))]


def activations(w):
    """dict muscle -> activation in [0, 1] of the synergy weights w (shape (4,))."""
    a = dict.fromkeys(MUSCLES, 0.0)
    for wk, name in zip(w, NAMES):
        for m, s in SYNERGIES[name].items():
            a[m] += float(wk) * s
    return {m: min(max(v, 0.0), 1.0) for m, v in a.items()}


def features(w):
    """phi(w): shape (..., 15) for w of shape (..., 4)."""
    w = np.asarray(w, dtype=float)
    quad = [w[..., i] * w[..., j] for i, j in _PAIRS]
    return np.concatenate([np.ones(w.shape[:-1] + (1,)), w, np.stack(quad, axis=-1)], axis=-1)


def feature_jacobian(w):
    """d phi / d w: shape (15, 4)."""
    n = len(NAMES)
    d = np.zeros((1 + n + len(_PAIRS), n))
    d[1:1 + n] = np.eye(n)
    for k, (i, j) in enumerate(_PAIRS):
        d[1 + n + k, i] += w[j]
        d[1 + n + k, j] += w[i]
    return d


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

    def __call__(self, w):
        g = self.coef @ features(w)
        x = g[self.floored] / self.s
        g[self.floored] = self.s * (np.maximum(x, 0.0) + np.log1p(np.exp(-np.abs(x))))
        return g

    def jacobian(self, w):
        """dy/dw: shape (3, 4)."""
        w = np.asarray(w, dtype=float)
        J = self.coef @ feature_jacobian(w)
        g = self.coef[self.floored] @ features(w)
        J[self.floored] *= (1.0 / (1.0 + np.exp(-g / self.s)))[:, None]
        return J

    def inverse(self, r, q, w0=None, lam=0.05, w_ref=None, iterations=30):
        """Weights w (shape (4,)) in [0, 1] minimizing J above for the desired outputs r
        (mm, shape (3,)) with output weights q (1/mm, shape (3,)); w0: warm start."""
        n = len(NAMES)
        w = np.full(n, 0.3) if w0 is None else np.clip(np.asarray(w0, dtype=float), 0, 1)
        w_ref = np.zeros(n) if w_ref is None else np.asarray(w_ref, dtype=float)
        q = np.asarray(q, dtype=float)
        r = np.asarray(r, dtype=float)

        def cost(w):
            return float(np.sum((q * (self(w) - r)) ** 2) + lam ** 2 * np.sum((w - w_ref) ** 2))

        c, mu = cost(w), 1e-3
        for _ in range(iterations):
            J = q[:, None] * self.jacobian(w)
            g = J.T @ (q * (self(w) - r)) + lam ** 2 * (w - w_ref)
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
