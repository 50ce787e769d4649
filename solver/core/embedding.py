"""Points embedded in bricks: host search and natural coordinates.

A point's host is the brick whose natural coordinates of it are smallest in the max
norm; the point is inside where max |xi| <= 1 + tol. A point outside every brick (a cable
end in the mouth slit, say) is tied to the nearest candidate with xi clamped to the
brick, so its displacement follows the closest point of that brick.
"""

import numpy as np
from scipy.spatial import cKDTree

from solver.core.element import shape_functions, shape_gradients


def natural_coordinates_batch(xe, points, iters=25):
    """xi (k, 3) with x(xi) = points in each brick: xe (k, 8, 3), points (k, 3)."""
    xi = np.zeros((len(points), 3))
    for _ in range(iters):
        r = np.einsum("ka,kaj->kj", shape_functions(xi), xe) - points
        jac = np.einsum("kai,kaj->kji", shape_gradients(xi), xe)     # dx_j / dxi_i
        bad = np.abs(np.linalg.det(jac)) < 1e-12
        jac[bad] = np.eye(3)
        step = np.linalg.solve(jac, -r[..., None])[..., 0]
        xi = np.clip(xi + step, -4.0, 4.0)
        if np.abs(step).max() < 1e-12:
            break
    return xi


def locate(mesh, points, candidates=16, tol=1e-6):
    """Hosts of points (p, 3) in mesh.

    Returns host (p,) brick index, xi (p, 3) natural coordinates (clamped to [-1, 1]),
    inside (p,) bool, gap (p,) mm: distance from the point to its host's clamped point.
    """
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    centroids = mesh.nodes[mesh.bricks].mean(axis=1)
    k = min(candidates, mesh.n_bricks)
    _, cand = cKDTree(centroids).query(points, k=k)
    cand = cand.reshape(len(points), k)
    pts = np.repeat(points, k, axis=0)
    xi = natural_coordinates_batch(mesh.nodes[mesh.bricks[cand.ravel()]], pts)
    score = np.abs(xi).max(axis=1).reshape(len(points), k)
    best = np.argmin(score, axis=1)
    rows = np.arange(len(points))
    host = cand[rows, best]
    xi = np.clip(xi.reshape(len(points), k, 3)[rows, best], -1.0, 1.0)
    inside = score[rows, best] <= 1.0 + tol
    proj = np.einsum("pa,paj->pj", shape_functions(xi), mesh.nodes[mesh.bricks[host]])
    return host, xi, inside, np.linalg.norm(proj - points, axis=1)
