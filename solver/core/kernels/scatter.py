"""Scatter of element matrices into a fixed CSR pattern."""

from numba import njit


@njit(cache=True)
def scatter_matrices(ke, index, data):
    """data[index[e, r, c]] += ke[e, r, c] for every block entry; ke, index (k, d, d)."""
    k, d, _ = ke.shape
    for e in range(k):
        for r in range(d):
            for c in range(d):
                data[index[e, r, c]] += ke[e, r, c]


@njit(cache=True)
def scatter_vectors(fe, dofs, out):
    """out[dofs[e, r]] += fe[e, r]; fe, dofs (k, d)."""
    k, d = fe.shape
    for e in range(k):
        for r in range(d):
            out[dofs[e, r]] += fe[e, r]
