"""Hyperelastic soft tissue: the brick kernels over the mesh (or a subset of its bricks).

A residual runs solver.core.kernels.brick_residual (forces only), an assembly with the tangent
solver.core.kernels.brick_tangent; both give solver.core.kernels.brick's forces, energy and tangent
to rounding (tests/test_element.py), which stays the reference implementation (and the
reduced-order model's kernel, solver.rom.kernels).
"""

import numpy as np

from solver.core.errors import ParameterError
from solver.core.kernels.brick import FORMULATIONS
from solver.core.kernels.brick_residual import brick_residual
from solver.core.kernels.brick_tangent import brick_tangent
from solver.core.terms.base import InvertedElement, Term


class Elasticity(Term):
    """Mooney-Rivlin bricks.

    mesh         solver.Mesh
    params       (m, 6) per-brick law parameters (c10, c01, c20, c11, c02, d), or (6,)
    formulation  'mean_dilatation' (default, locking-free) or 'full'
    subset       optional brick indices (k,): the term covers only those bricks, and
                 params is then (k, 6) or (6,)
    modifiers    terms that add to the parameters of some of its bricks in its own pass
                 (their ``added_params(lam)`` -> (positions (j,), dparams (j, 6)) or None;
                 solver.face.terms.stiffening with a host)
    """

    name = "elasticity"

    def __init__(self, mesh, params, formulation="mean_dilatation", subset=None):
        if formulation not in FORMULATIONS:
            raise ParameterError(f"formulation {formulation!r} is not one of "
                                 f"{sorted(FORMULATIONS)}")
        self.mesh = mesh
        self.subset = np.arange(mesh.n_bricks) if subset is None else np.asarray(subset)
        self.bricks = np.ascontiguousarray(mesh.bricks[self.subset])
        self.form = FORMULATIONS[formulation]
        self.formulation = formulation
        m = len(self.subset)
        self.params = np.ascontiguousarray(
            np.broadcast_to(np.asarray(params, dtype=np.float64), (m, 6))).copy()
        self._dndX = np.ascontiguousarray(mesh.dn_dx[self.subset])
        self._w = np.ascontiguousarray(mesh.det_j[self.subset])
        self._fe = np.empty((m, 24))
        self._ke = np.empty((m, 24, 24))
        self._energy = np.empty(m)
        self._jmin = np.empty(m)
        self.min_det_f = 1.0
        self.modifiers = []

    def _params(self, lam):
        """(m, 6) the parameters of this pass: params plus what the modifiers add."""
        params = self.params
        for mod in self.modifiers:
            added = mod.added_params(lam)
            if added is not None:
                params = params.copy() if params is self.params else params
                params[added[0]] += added[1]
        return params

    def blocks(self):
        return [self.bricks]

    def assemble(self, state, asm, block_ids):
        params = self._params(state.lam)
        if asm.need_k:
            brick_tangent(state.u, self.bricks, self._dndX, self._w, params, self.form,
                          self._fe, self._ke, self._energy, self._jmin)
        else:
            brick_residual(state.u, self.bricks, self._dndX, self._w, params, self.form,
                           self._fe, self._energy, self._jmin)
        e = int(np.argmin(self._jmin))
        self.min_det_f = float(self._jmin[e])
        if not self.min_det_f > 0.0:
            raise InvertedElement(self.name, int(self.mesh.element_ids[self.subset[e]]),
                                  self.min_det_f)
        asm.energy += float(self._energy.sum())
        asm.add_block(block_ids[0], self._fe, self._ke if asm.need_k else None)
