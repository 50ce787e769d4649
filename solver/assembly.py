"""Global assembly into a sparsity pattern built once per model.

Every term declares its element blocks up front: node connectivities (k, nloc). The
pattern (CSR over all 3 n DOFs) is the union of all blocks' couplings; each block keeps
an index array (k, 3 nloc, 3 nloc) into the CSR data, so that an assembly is a plain
scatter of element matrices into one data vector. Constraints are applied by gathering
the free-free part of that vector into a second, precomputed CSR pattern.
"""

import numpy as np
import scipy.sparse as sp

from .kernels.scatter import scatter_matrices, scatter_vectors


def block_dofs(conn):
    """(k, nloc) node ids -> (k, 3 nloc) DOF ids, node-major."""
    conn = np.asarray(conn, dtype=np.int64)
    return (3 * conn[:, :, None] + np.arange(3)).reshape(len(conn), -1)


class Pattern:
    """CSR pattern over ndof DOFs for a list of node connectivity blocks.

    blocks   list of (k, nloc) int arrays
    After construction: indptr, indices, nnz, and index[b] (k, d, d) for each block b.
    """

    def __init__(self, ndof, blocks):
        self.ndof = ndof
        dofs = [block_dofs(b) for b in blocks]
        rows = [np.repeat(d, d.shape[1], axis=1).ravel() for d in dofs]
        cols = [np.tile(d, (1, d.shape[1])).ravel() for d in dofs]
        diag = np.arange(ndof, dtype=np.int64)          # keep the diagonal for every DOF
        r = np.concatenate(rows + [diag])
        c = np.concatenate(cols + [diag])
        key = r * ndof + c
        ukey, inv = np.unique(key, return_inverse=True)
        ur, uc = ukey // ndof, ukey % ndof
        self.indices = uc.astype(np.int32)
        self.indptr = np.zeros(ndof + 1, dtype=np.int32)
        np.cumsum(np.bincount(ur, minlength=ndof), out=self.indptr[1:])
        self.nnz = len(ukey)
        self._keys = ukey
        self.diagonal = self.locate(diag, diag)                          # (ndof,) data index
        self.dofs = dofs
        self.index = []
        start = 0
        for d in dofs:
            n = d.shape[0] * d.shape[1] ** 2
            self.index.append(inv[start:start + n].reshape(d.shape[0], d.shape[1], d.shape[1]))
            start += n

    def matrix(self, data):
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.ndof, self.ndof))

    def locate(self, rows, cols):
        """Data indices of entries (rows, cols), which must be in the pattern."""
        keys = np.asarray(rows, dtype=np.int64) * self.ndof + np.asarray(cols, dtype=np.int64)
        idx = np.searchsorted(self._keys, keys)
        if np.any(idx >= self.nnz) or np.any(self._keys[np.minimum(idx, self.nnz - 1)] != keys):
            raise ValueError("entries outside the sparsity pattern")
        return idx


class Assembly:
    """Residual and tangent data being accumulated for one state.

    residual (ndof,), data (nnz,) the CSR values of the tangent, energy (scalar).
    """

    def __init__(self, pattern, need_k):
        self.pattern = pattern
        self.need_k = need_k
        self.residual = np.zeros(pattern.ndof)
        self.data = np.zeros(pattern.nnz) if need_k else None
        self.energy = 0.0

    def add_block(self, block, fe, ke=None, rows=None):
        """fe (k, d) into the residual; ke (k, d, d) into the tangent (when needed).
        rows: (m,) indices of the block's elements that fe, ke (m, ...) belong to (a
        subset, e.g. the active contact pairs); default all k."""
        dofs, index = self.pattern.dofs[block], self.pattern.index[block]
        if rows is not None:
            dofs, index = dofs[rows], index[rows]
        scatter_vectors(fe, dofs, self.residual)
        if self.need_k and ke is not None:
            scatter_matrices(ke, index, self.data)

    def add_diagonal(self, values):
        """values (ndof,) onto the tangent's diagonal."""
        if self.need_k:
            self.data[self.pattern.diagonal] += values

    def matrix(self):
        return self.pattern.matrix(self.data)


class Reduction:
    """Restriction of the CSR pattern to the free DOFs (precomputed gather)."""

    def __init__(self, pattern, free):
        self.free = np.asarray(free, dtype=np.int64)
        mask = np.zeros(pattern.ndof, dtype=bool)
        mask[self.free] = True
        new = -np.ones(pattern.ndof, dtype=np.int64)
        new[self.free] = np.arange(len(self.free))
        rows = np.repeat(np.arange(pattern.ndof), np.diff(pattern.indptr))
        keep = mask[rows] & mask[pattern.indices]
        self.take = np.flatnonzero(keep)
        r = new[rows[keep]]
        self.indices = new[pattern.indices[keep]].astype(np.int32)
        self.indptr = np.zeros(len(self.free) + 1, dtype=np.int32)
        np.cumsum(np.bincount(r, minlength=len(self.free)), out=self.indptr[1:])
        self.n = len(self.free)

    def matrix(self, data):
        """K_ff as CSR from the full data vector."""
        return sp.csr_matrix((data[self.take], self.indices, self.indptr),
                             shape=(self.n, self.n))
