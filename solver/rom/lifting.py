r"""The lifting of the reduced model: the jaw's prescribed motion, u = V q + L(p).

The jaw (solver.face.jaw) prescribes the displacements of the mandible's nodes: a rigid
motion of the pose p = (opening deg, protrusion mm). The basis V has zero rows on every
prescribed DOF, so the reduced displacements are

    u = V q + L(p),   L(p) (n, 3): the mandible's nodes' rigid displacements, 0 elsewhere,

and everything the reduced step evaluates takes the lifting along:

* the cubature's bricks: u_e = V_e q + L_e(p) (the kernels' `le` (k, 24));
* the cables: x_q - x_p = d0_c(p) + D_c q, d0_c(p) the difference of the end points'
  reference positions at p (insertions on the mandible moved, solver.face.terms.cables)
  plus the interpolated L of their host nodes;
* contact: the contact nodes at X + L + V q, the lower teeth moved to p (solver.rom.contact);
* the lip outputs and the trust check's full-order residual.

Inertia: the mass is lumped, so the prescribed DOFs' accelerations do not load the free
ones. Damping: beta K_n (u - u_n) / h does couple them; the bricks' damping force is
evaluated on u_e - u_e,n with the lifting in both (L_e(p) - L_e(p_n): the jaw's velocity
damped through the tissue, as in the full model, solver.core.terms.inertia).

With the jaw closed (p = 0) L is exactly 0, and so is every term above.
"""

import numpy as np


class Lifting:
    """face: solver.face.face_model.FaceModel (its jaw, or None); conn (k, 8): the
    cubature's bricks' nodes; cables: solver.face.terms.cables.Cables or None."""

    def __init__(self, face, conn, cables=None):
        self.jaw = face.jaw
        self.n = face.anatomy.mesh.n_nodes
        self.conn = np.asarray(conn, dtype=np.int64)
        self.cables = cables
        if cables is not None:
            self._cnodes = cables.nodes.reshape(-1, 2, 8)
        self._last = None                       # (pose bytes, L, le, d0)

    def _compute(self, pose):
        L = np.zeros((self.n, 3))
        if self.jaw is not None and np.any(pose != 0.0):
            L[self.jaw.geometry.nodes] = self.jaw.displacement(pose)
        le = np.ascontiguousarray(L[self.conn].reshape(len(self.conn), 24))
        d0 = None
        if self.cables is not None:
            X = self.cables.rest_points_at(pose)
            d0 = X[:, 1] - X[:, 0]
            if np.any(L):
                Lc = np.einsum("cpa,cpaj->cpj", self.cables.w, L[self._cnodes])
                d0 = d0 + Lc[:, 1] - Lc[:, 0]
            d0 = np.ascontiguousarray(d0)
        return L, le, d0

    def at(self, pose):
        """(L (n, 3), le (k, 24), d0 (c, 3) or None) at a pose (2,); the arrays are shared
        between calls at the same pose (read only)."""
        pose = np.asarray(pose if pose is not None else (0.0, 0.0), dtype=np.float64)
        key = pose.tobytes()
        if self._last is None or self._last[0] != key:
            self._last = (key, *self._compute(pose))
        return self._last[1:]
