"""What both contact terms share: the penalty constants (N/mm^3, mm), the check of
a penalty and smoothing, and the report of an assembly (gaps, forces, penetration)."""

import numpy as np

from solver.core.errors import ParameterError


PENALTY = 1.0              # N/mm^3: contact pressure per mm of penetration


TEETH_PENALTY = 2.0        # N/mm^3: lips and cheeks on the rigid teeth (BUC at 1 presses a
                           # cheek node of 5 mm^2 with 0.35 N: 0.035 mm deep)


EDGE_FADE = 1.0            # mm: lip contact fades out over this distance beyond a free edge


TOLERANCE = 0.05           # mm: the deepest penetration the penalty is meant to allow (checks)


FACING_TOLERANCE = 1e-6    # mm: a slave this far behind a master triangle's plane still faces it


def check_penalty(penalty, smoothing):
    if not penalty > 0:
        raise ParameterError(f"penalty = {penalty!r} must be > 0 (N/mm^3)")
    if not smoothing >= 0:
        raise ParameterError(f"smoothing = {smoothing!r} must be >= 0 (mm)")


class ContactReport:
    """Contact measures of the last assembly (see the module docstring); ``touching()``
    (n,) bool: the mesh nodes the contact pushed on then (solver.core.transient leaves the nodes
    touched at either end of a step out of its error estimate)."""

    nonsmooth = True

    def touching(self):
        return np.any(self.nodal_force != 0.0, axis=1)

    @property
    def penalty(self):
        """N/mm^3; setting it rescales the slaves' stiffnesses (an experiment's knob:
        benchmarks/fast_path.py --set contact.penalty=P)."""
        return self._penalty

    @penalty.setter
    def penalty(self, value):
        check_penalty(value, self.smoothing)
        scale = value / self._penalty
        for k in self._stiffnesses():
            k *= scale
        self._penalty = float(value)

    def _report(self, gap, force, nodal_force):
        active = gap <= 0
        self.gap, self.force, self.nodal_force = gap, force, nodal_force
        self.n_active = int(active.sum())
        self.max_penetration = float(-gap[active].min()) if self.n_active else 0.0
        self.total_force = float(force.sum())
