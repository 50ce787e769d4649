"""Hyperelastic soft tissue: the brick kernel over the whole mesh."""

import numpy as np

from ..kernels.brick import FORMULATIONS, brick_forces
from ..errors import ParameterError
from .base import InvertedElement, Term


class Elasticity(Term):
    """Mooney-Rivlin bricks.

    mesh         solver.Mesh
    params       (m, 6) per-brick law parameters (c10, c01, c20, c11, c02, d), or (6,)
    formulation  'mean_dilatation' (default, locking-free) or 'full'
    """

    name = "elasticity"

    def __init__(self, mesh, params, formulation="mean_dilatation"):
        if formulation not in FORMULATIONS:
            raise ParameterError(f"formulation {formulation!r} is not one of "
                                 f"{sorted(FORMULATIONS)}")
        self.mesh = mesh
        self.form = FORMULATIONS[formulation]
        self.formulation = formulation
        self.base_params = np.ascontiguousarray(
            np.broadcast_to(np.asarray(params, dtype=np.float64), (mesh.n_bricks, 6)))
        self.params = self.base_params.copy()   # what the kernel sees (stiffening scales it)
        m = mesh.n_bricks
        self._dndX = np.ascontiguousarray(mesh.dn_dx)
        self._w = np.ascontiguousarray(mesh.det_j)
        self._fe = np.empty((m, 24))
        self._ke = np.empty((m, 24, 24))
        self._energy = np.empty(m)
        self._jmin = np.empty(m)
        self.min_det_f = 1.0

    def blocks(self):
        return [self.mesh.bricks]

    def assemble(self, state, asm, block_ids):
        brick_forces(state.u, self.mesh.bricks, self._dndX, self._w, self.params, self.form,
                     asm.need_k, self._fe, self._ke, self._energy, self._jmin)
        e = int(np.argmin(self._jmin))
        self.min_det_f = float(self._jmin[e])
        if not self.min_det_f > 0.0:
            raise InvertedElement(self.name, int(self.mesh.element_ids[e]), self.min_det_f)
        asm.energy += float(self._energy.sum())
        asm.add_block(block_ids[0], self._fe, self._ke if asm.need_k else None)
