r"""Energy-conserving sampling and weighting (ECSW): an empirical cubature of the
reduced internal force.

The reduced internal force is a sum over the bricks, V^T f(V q) = sum_e g_e(q) with
g_e = V_e^T f_e(V_e q) (r,). Over training states q_1 ... q_s the columns
G[:, e] = (g_e(q_1); ...; g_e(q_s)) (s r,) and b = sum_e G[:, e] (so w = 1 solves
G w = b exactly). ECSW looks for a sparse w >= 0 with

    |G w - b| <= tol |b|,

and the online force is then sum_{e: w_e > 0} w_e V_e^T f_e(V_e q). Non-negative weights
keep the reduced operator a sum of element energies with positive weights: the reduced
tangent stays symmetric and, where the bricks' tangents are, positive.

Rows are scaled per training state by 1 / |b_s| so that small and large deformations
count alike. The sparse non-negative solution is the greedy active-set (Lawson-Hanson)
NNLS stopped at the tolerance: add the brick most correlated with the residual,
G_E^T (b - G w), solve the unconstrained least squares on the active set E, and when a
weight would turn negative step back along the segment to the first zero and drop it.
"""

import numpy as np


def scale_rows(G, b, r):
    """G, b with each state's block of r rows divided by that block's |b_s|."""
    s = len(b) // r
    norms = np.linalg.norm(b.reshape(s, r), axis=1)
    scale = np.repeat(1.0 / np.maximum(norms, 1e-300 + 1e-12 * norms.max()), r)
    return G * scale[:, None], b * scale


def ecsw(G, b, tol=1e-2, max_elements=None):
    """Sparse non-negative weights w (N,) with |G w - b| <= tol |b| (or the best reached
    with max_elements bricks); returns (w, relative residual)."""
    m, N = G.shape
    max_elements = max_elements or N
    bn = np.linalg.norm(b)
    w = np.zeros(N)
    active = np.zeros(N, dtype=bool)
    banned = np.zeros(N, dtype=bool)         # added and dropped at once (rounding)
    res = b.copy()
    while np.linalg.norm(res) > tol * bn and active.sum() < max_elements:
        mu = G.T @ res
        mu[active | banned] = -np.inf
        e = int(np.argmax(mu))
        if mu[e] <= 0:
            break
        active[e] = True
        while True:
            idx = np.flatnonzero(active)
            if len(idx) == 0:
                break
            z = np.linalg.lstsq(G[:, idx], b, rcond=None)[0]
            if np.all(z > 0):
                w[:] = 0.0
                w[idx] = z
                break
            neg = z <= 0
            wi = w[idx]
            alpha = np.min(wi[neg] / (wi[neg] - z[neg]))
            w[idx] = wi + alpha * (z - wi)
            drop = idx[w[idx] <= 1e-14 * max(1.0, w.max())]
            active[drop] = False
            w[drop] = 0.0
            if e in drop:
                banned[e] = True
        res = b - G @ w
    return w, float(np.linalg.norm(res) / bn)
