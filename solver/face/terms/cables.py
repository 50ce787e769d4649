"""Muscle cables embedded in the bricks they lie in (see solver.core.kernels.cable).

A cable end on bone (an insertion) is a fixed point; where the muscle inserts on the
mandible (solver.face.jaw.MANDIBLE_MUSCLES) it follows the jaw's pose along the load path.
"""

import numpy as np

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.core.element import shape_functions
from solver.core.embedding import locate
from solver.face.jaw import MANDIBLE_MUSCLES
from solver.core.kernels.cable import cable_forces
from solver.core.terms.base import Term


class Cables(Term):
    """The cables of the driven muscles only.

    anatomy     solver.face.anatomy.Anatomy (its fibres of the driven muscles are used)
    muscles     names of the driven muscles
    properties  solver.face.muscles.MuscleProperties
    activation  solver.face.activation.Activation (shared with the stiffening term)
    jaw         solver.face.jaw.Jaw or None: moves the insertions of the muscles on the mandible
    """

    name = "cables"

    def __init__(self, anatomy, muscles, properties, activation, jaw=None):
        self.properties, self.activation, self.jaw = properties, activation, jaw
        fibres = [f for f in anatomy.fibres if f.muscle in muscles]
        self.fibres = fibres
        mesh = anatomy.mesh
        pts = np.vstack([f.points for f in fibres])
        fixed = np.concatenate([f.insertion for f in fibres])
        host, xi, self.inside, self.gap = locate(mesh, pts)
        w = shape_functions(xi)
        w[fixed] = 0.0                                   # insertions: fixed on bone
        start = np.cumsum([0] + [len(f.points) for f in fibres])
        ends = np.concatenate([np.column_stack([np.arange(s, e - 1), np.arange(s + 1, e)])
                               for s, e in zip(start[:-1], start[1:])])
        self.muscle = np.concatenate([[MUSCLE_NAMES.index(f.muscle)] * f.n_cables
                                      for f in fibres])
        self.X = np.ascontiguousarray(pts[ends])                     # (c, 2, 3)
        self.w = np.ascontiguousarray(w[ends])                       # (c, 2, 8)
        self.nodes = np.ascontiguousarray(mesh.bricks[host[ends]].reshape(len(ends), 16))
        self.L0 = np.linalg.norm(self.X[:, 1] - self.X[:, 0], axis=1)
        E = properties.youngs_modulus()
        self.AE = np.array([properties.area(MUSCLE_NAMES[m]) * E for m in self.muscle])
        on_jaw = fixed & np.concatenate([[f.muscle in MANDIBLE_MUSCLES] * len(f.points)
                                         for f in fibres])
        self.jaw_ends = on_jaw[ends] if jaw is not None else np.zeros(ends.shape, bool)
        self._X = self.X                                # at the last assembled pose
        c = len(ends)
        self._fe, self._ke = np.empty((c, 48)), np.empty((c, 48, 48))
        self.tension = np.zeros(c)

    def blocks(self):
        return [self.nodes]

    def active_strain(self, lam):
        """(c,) each cable's active strain at load factor lam (its muscle's, made once
        per muscle)."""
        a = self.activation.at(lam)
        per = np.array([self.properties.active_strain(name, a[m])
                        for m, name in enumerate(MUSCLE_NAMES)])
        return per[self.muscle]

    def point_positions(self, u):
        """(c, 2, 3) current cable end positions for displacements u (n, 3)."""
        return self._X + np.einsum("cpa,cpaj->cpj", self.w,
                                   u[self.nodes.reshape(-1, 2, 8)])

    def rest_points(self, lam):
        """(c, 2, 3) the cable ends' reference positions at load factor lam: the rest
        positions, the mandible's insertions moved by the jaw's pose."""
        if self.jaw is None or not self.jaw.moving or not self.jaw_ends.any():
            return self.X
        return self.rest_points_at(self.jaw.at(lam))

    def rest_points_at(self, pose):
        """(c, 2, 3) the cable ends' reference positions at a jaw pose (2,) (opening deg,
        protrusion mm): the rest positions, the mandible's insertions moved rigidly."""
        if self.jaw is None or not self.jaw_ends.any() or not np.any(np.asarray(pose)):
            return self.X
        X = self.X.copy()
        X[self.jaw_ends] = self.jaw.geometry.transform(self.X[self.jaw_ends], pose)
        return X

    def assemble(self, state, asm, block_ids):
        e = self.active_strain(state.lam)
        self._X = self.rest_points(state.lam)
        asm.energy += cable_forces(state.u, self._X, self.w, self.nodes, self.AE, self.L0, e,
                                   asm.need_k, self._fe, self._ke, self.tension)
        asm.add_block(block_ids[0], self._fe, self._ke if asm.need_k else None)

    def load_scale(self, lam):
        """The active forces' scale (N)."""
        return float(np.linalg.norm(self.AE * self.active_strain(lam)))

