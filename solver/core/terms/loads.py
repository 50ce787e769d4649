"""Nodal forces that ramp with the load factor."""

import numpy as np

from solver.core.terms.base import Term


class NodalForces(Term):
    """External nodal forces f (ndof,) N, applied as lam * f (a dead load)."""

    name = "nodal_forces"

    def __init__(self, ndof):
        self.target = np.zeros(ndof)
        self.start = np.zeros(ndof)

    def add(self, dofs, values):
        np.add.at(self.target, dofs, values)

    def current(self, lam):
        return self.start + lam * (self.target - self.start)

    def assemble(self, state, asm, block_ids):
        f = self.current(state.lam)
        asm.residual -= f
        asm.energy -= float(f @ state.u.ravel())

    def commit(self, state):
        if state.lam >= 1.0:
            self.start = self.target.copy()

    def load_scale(self, lam):
        return float(np.linalg.norm(self.current(lam)))
