"""Strains at brick centres: Green-Lagrange and logarithmic (Hencky) principal strains.

ANSYS reports logarithmic strains in large-deformation analyses; the paper's Table 4 is
read against the logarithmic principal strains here: eps_i = ln(lambda_i), lambda_i^2 the
eigenvalues of C = F^T F at the brick centre (negative: compression).
"""

import numpy as np

from solver.core.element import shape_gradients


def displacement_gradients(mesh, u, bricks=None):
    """(k, 3, 3) du_i/dX_j at the centres of the bricks (default: all) for u (n, 3)."""
    idx = np.arange(mesh.n_bricks) if bricks is None else np.asarray(bricks)
    dn_dxi = shape_gradients(np.zeros(3))                           # (8, 3)
    conn = mesh.bricks[idx]
    jac = np.einsum("ak,maj->mjk", dn_dxi, mesh.nodes[conn])        # dX_j / dxi_k
    dn_dx = np.einsum("ak,mkj->maj", dn_dxi, np.linalg.inv(jac))     # (k, 8, 3)
    return np.einsum("mai,maj->mij", np.asarray(u, dtype=np.float64)[conn], dn_dx)


def green_lagrange_strain(mesh, u, bricks=None):
    """(k, 3, 3) E = (F^T F - I) / 2 at brick centres."""
    h = displacement_gradients(mesh, u, bricks)
    return 0.5 * (h + h.transpose(0, 2, 1) + np.einsum("mki,mkj->mij", h, h))


def principal_strains(strain):
    """(k, 3) eigenvalues of symmetric strains (k, 3, 3), largest first."""
    return np.linalg.eigvalsh(strain)[:, ::-1]


def log_principal_strains(mesh, u, bricks=None):
    """(k, 3) logarithmic principal strains ln(lambda_i), largest first."""
    E = green_lagrange_strain(mesh, u, bricks)
    return 0.5 * np.log1p(2.0 * principal_strains(E))
