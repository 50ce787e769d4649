"""Trilinear 8-node brick: shape functions, 2x2x2 Gauss rule, reference gradients.

Node order is ANSYS's (SOLID185, I..P): the bottom face I J K L counter-clockwise seen
from the top, then the top face M N O P above it. Natural coordinates of node a are
(xi_a, eta_a, zeta_a) in {-1, 1}^3, and

    N_a(xi, eta, zeta) = (1 + xi_a xi)(1 + eta_a eta)(1 + zeta_a zeta) / 8.

A wedge (prism) is a brick with repeated node ids, as ANSYS writes it (K = L and O = P).
Its shape functions are the sums of the brick's over the coincident nodes, which the
assembly produces by itself: both local nodes scatter into the same global DOF. det J
vanishes on the collapsed edge but stays positive at the 2x2x2 Gauss points.
"""

import numpy as np

NODE_XI = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
     [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=np.float64)

_g = 1.0 / np.sqrt(3.0)
GAUSS_POINTS = NODE_XI * _g          # (8, 3): one point per octant


def shape_functions(xi):
    """N (..., 8) at natural coordinates xi (..., 3)."""
    xi = np.asarray(xi, dtype=np.float64)
    f = 1.0 + xi[..., None, :] * NODE_XI        # (..., 8, 3)
    return f.prod(axis=-1) / 8.0


def shape_gradients(xi):
    """dN/dxi (..., 8, 3) at natural coordinates xi (..., 3)."""
    xi = np.asarray(xi, dtype=np.float64)
    f = 1.0 + xi[..., None, :] * NODE_XI        # (..., 8, 3)
    g = np.empty(f.shape)
    g[..., 0] = NODE_XI[:, 0] * f[..., 1] * f[..., 2]
    g[..., 1] = NODE_XI[:, 1] * f[..., 0] * f[..., 2]
    g[..., 2] = NODE_XI[:, 2] * f[..., 0] * f[..., 1]
    return g / 8.0


DN_DXI = shape_gradients(GAUSS_POINTS)     # (8 gp, 8 nodes, 3)
N_GP = shape_functions(GAUSS_POINTS)       # (8 gp, 8 nodes)


def reference_geometry(nodes, bricks):
    """Jacobian determinants and reference gradients at the Gauss points.

    nodes (n, 3), bricks (m, 8) -> detJ (m, 8 gp), dN/dX (m, 8 gp, 8 nodes, 3).
    dN/dX is NaN-free only where detJ > 0.
    """
    from solver.core.kernels.geometry import brick_geometry

    bricks = np.ascontiguousarray(bricks, dtype=np.int64)
    det = np.empty((len(bricks), 8))
    dndx = np.empty((len(bricks), 8, 8, 3))
    brick_geometry(np.ascontiguousarray(nodes, dtype=np.float64), bricks, DN_DXI, det, dndx)
    return det, dndx


def natural_coordinates(xe, point, tol=1e-10, max_iter=50):
    """Natural coordinates of a physical point in one brick (Newton on x(xi) = point).

    xe (8, 3) brick node coordinates, point (3,). Returns xi (3,); the point is inside
    (or on) the brick where max |xi| <= 1 up to a tolerance.
    """
    xi = np.zeros(3)
    for _ in range(max_iter):
        r = shape_functions(xi) @ xe - point
        jac = shape_gradients(xi).T @ xe                 # (3 k, 3 j): dx_j/dxi_k
        step = np.linalg.lstsq(jac.T, -r, rcond=None)[0]
        xi = np.clip(xi + step, -3.0, 3.0)
        if np.linalg.norm(step) < tol:
            break
    return xi
