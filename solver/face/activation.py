"""Muscle activations along a load path: from the last converged values to new targets."""

import math

import numpy as np

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.core.errors import ParameterError


def check_activation(name, value):
    """A float in [0, 1], or a ParameterError naming the muscle and the value."""
    if name not in MUSCLE_NAMES:
        raise ParameterError(f"unknown muscle {name!r}; known: {', '.join(MUSCLE_NAMES)}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"activation {name} = {value!r} is not a number") from None
    if not math.isfinite(v) or v < 0.0 or v > 1.0:
        raise ParameterError(f"activation {name} = {value!r} is outside [0, 1]")
    return v


class Activation:
    """start, target (10,) in MUSCLE_NAMES order; at(lam) interpolates between them.
    Written by solver.face.face_model.FaceModel alone (targets checked by the caller,
    solver.app.simulation.Simulation.set_activations); terms only read it."""

    def __init__(self):
        self.start = np.zeros(len(MUSCLE_NAMES))
        self.target = np.zeros(len(MUSCLE_NAMES))

    def set(self, values):
        """values: dict muscle -> activation in [0, 1], already checked (check_activation);
        the others keep their targets."""
        for m, v in dict(values).items():
            self.target[MUSCLE_NAMES.index(m)] = float(v)

    def at(self, lam):
        return self.start + lam * (self.target - self.start)

    def commit(self):
        self.start = self.target.copy()

    def as_dict(self, values=None):
        values = self.target if values is None else values
        return {m: float(v) for m, v in zip(MUSCLE_NAMES, values)}
