r"""Proper orthogonal decomposition of displacement snapshots on the free DOFs.

Snapshots U = [u_1 ... u_s] (n_free, s), displacements in mm. The thin SVD
U = Phi Sigma W^T gives the basis V = Phi[:, :r], orthonormal (V^T V = I), and the
best rank-r approximation of the snapshots in the Frobenius norm:

    sum_j |u_j - V V^T u_j|^2 = sum_{i > r} sigma_i^2.

The size r is the smallest whose captured energy sum_{i <= r} sigma_i^2 / sum_i sigma_i^2
reaches `energy` (default 1 - 1e-6: a relative residual of 1e-3 in the Frobenius norm),
at least r_min and at most r_max. No mean is subtracted: the rest state u = 0 is part of
the model (q = 0), and every snapshot is reproduced from it.
"""

import numpy as np


def pod_basis(snapshots, energy=1.0 - 1e-6, r_min=1, r_max=None):
    """(V (n, r), sigma (s,)): the POD basis of the columns of snapshots (n, s)."""
    U = np.asarray(snapshots, dtype=np.float64)
    phi, sigma, _ = np.linalg.svd(U, full_matrices=False)
    return phi[:, :basis_size(sigma, energy, r_min, r_max)].copy(), sigma


def basis_size(sigma, energy=1.0 - 1e-6, r_min=1, r_max=None):
    """The smallest r with captured energy >= energy, clipped to [r_min, r_max]."""
    e = np.cumsum(sigma ** 2)
    if e[-1] == 0:
        return max(r_min, 1)
    r = int(np.searchsorted(e / e[-1], energy) + 1)
    r = max(r, r_min)
    return min(r, r_max or len(sigma), len(sigma))


def captured_energy(sigma, r):
    """sum_{i <= r} sigma_i^2 / sum_i sigma_i^2."""
    e = sigma ** 2
    return float(e[:r].sum() / e.sum()) if e.sum() > 0 else 1.0

