"""The lip outputs of a reduced state, read from the few nodes they need.

solver.face.face_model.FaceModel.lip_outputs(u) on u = V q reconstructs every node; the measures
read only the mid-sagittal lip contours and a few landmarks. LipOutputs reconstructs
those nodes (V restricted to them, once) and computes the same measures: the aperture by
a numba transcription of solver.face.aperture.contour_gap (same formulas; tests compare the
two), the protrusions and the width as lip_outputs does.
"""

import numpy as np
from numba import njit

from solver.core import _cache  # noqa: F401  (the solver's kernel cache, before any @njit)


@njit(cache=True)
def _seg_dist(a0, a1, q0, q1):
    """Distance from the point a to the segment q0 q1 (solver.face.aperture._point_segment)."""
    d0, d1 = q1[0] - q0[0], q1[1] - q0[1]
    w0, w1 = a0 - q0[0], a1 - q0[1]
    s = (w0 * d0 + w1 * d1) / max(d0 * d0 + d1 * d1, 1e-300)
    s = min(max(s, 0.0), 1.0)
    e0, e1 = w0 - s * d0, w1 - s * d1
    return np.sqrt(e0 * e0 + e1 * e1)


@njit(cache=True)
def contour_gap(yz, upper, lower):
    """solver.face.aperture.contour_gap: the smallest distance (mm) between the segments upper
    (ku, 2) and lower (kl, 2) (node ids into yz (n, 2)); 0 where two cross."""
    best = np.inf
    for i in range(upper.shape[0]):
        p0, p1 = yz[upper[i, 0]], yz[upper[i, 1]]
        for j in range(lower.shape[0]):
            q0, q1 = yz[lower[j, 0]], yz[lower[j, 1]]
            dq0, dq1 = q1[0] - q0[0], q1[1] - q0[1]
            dp0, dp1 = p1[0] - p0[0], p1[1] - p0[1]
            c1 = dq0 * (p0[1] - q0[1]) - dq1 * (p0[0] - q0[0])
            c2 = dq0 * (p1[1] - q0[1]) - dq1 * (p1[0] - q0[0])
            c3 = dp0 * (q0[1] - p0[1]) - dp1 * (q0[0] - p0[0])
            c4 = dp0 * (q1[1] - p0[1]) - dp1 * (q1[0] - p0[0])
            if c1 * c2 < 0.0 and c3 * c4 < 0.0:
                return 0.0
            best = min(best, _seg_dist(p0[0], p0[1], q0, q1), _seg_dist(p1[0], p1[1], q0, q1),
                       _seg_dist(q0[0], q0[1], p0, p1), _seg_dist(q1[0], q1[1], p0, p1))
    return best


class LipOutputs:
    """lip_outputs(q, L): FaceModel.lip_outputs(V q + L) from the nodes it reads only."""

    def __init__(self, face, V):
        mesh, lm = face.anatomy.mesh, face.anatomy.landmarks
        self.upper, self.lower = (np.ascontiguousarray(c, dtype=np.int64)
                                  for c in face.lip_contours)
        self.lm = {k: int(v) for k, v in lm.items()}
        nodes = np.unique(np.concatenate([self.upper.ravel(), self.lower.ravel(),
                                          np.fromiter(self.lm.values(), dtype=np.int64)]))
        self.nodes = nodes
        n, r = mesh.n_nodes, V.shape[1]
        self.Vo = np.ascontiguousarray(V.reshape(n, 3, r)[nodes].reshape(3 * len(nodes), r))
        self.X = mesh.nodes
        self.u = np.zeros((n, 3))
        self.x = mesh.nodes.copy()

    def __call__(self, q, L=None):
        """The lip outputs of u = V q + L (L (n, 3): the jaw's lifting, or None)."""
        u, x = self.u, self.x
        u[self.nodes] = (self.Vo @ q).reshape(-1, 3)
        if L is not None:
            u[self.nodes] += L[self.nodes]
        x[self.nodes] = self.X[self.nodes] + u[self.nodes]
        lm = self.lm
        out = {"lip_aperture": float(contour_gap(x[:, 1:], self.upper, self.lower))}
        out["upper_lip_protrusion"] = float(u[lm["upper_lip_front"], 1])
        out["lower_lip_protrusion"] = float(u[lm["lower_lip_front"], 1])
        out["lip_protrusion"] = 0.5 * (out["upper_lip_protrusion"]
                                       + out["lower_lip_protrusion"])
        if "corner_right" in lm:
            out["lip_width"] = float(np.linalg.norm(x[lm["corner_right"]]
                                                    - x[lm["corner_left"]]))
        else:
            out["lip_width"] = float(2.0 * abs(x[lm["corner_left"], 0]))
        return out
