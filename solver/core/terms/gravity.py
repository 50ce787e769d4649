"""Gravity: a dead body force m_a g on every node (lumped masses), g in mm/s^2."""

import numpy as np

from solver.core.terms.base import Term
from solver.core.terms.inertia import lumped_masses

G_MM_S2 = 9810.0


class Gravity(Term):
    """direction (3,) unit vector; density tonne/mm^3."""

    name = "gravity"

    def __init__(self, mesh, density, direction, g=G_MM_S2):
        d = np.asarray(direction, dtype=float)
        self.force = (lumped_masses(mesh, density)[:, None] * (g * d / np.linalg.norm(d))).ravel()

    def assemble(self, state, asm, block_ids):
        asm.residual -= self.force
        asm.energy -= float(self.force @ state.u.ravel())

    def load_scale(self, lam):
        return float(np.linalg.norm(self.force))
