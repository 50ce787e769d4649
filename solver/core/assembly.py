"""Global assembly into a sparsity pattern built once per model.

Every term declares its element blocks up front: node connectivities (k, nloc). The
pattern (CSR over all 3 n DOFs) is the union of all blocks' couplings; each block keeps
an index array (k, 3 nloc, 3 nloc) into the CSR data, so that an assembly is a plain
scatter of element matrices into one data vector. Constraints are applied by gathering
the free-free part of that vector into a second, precomputed CSR pattern.
"""

import numpy as np
import scipy.sparse as sp

from solver.core.kernels.scatter import scatter_matrices, scatter_vectors


def block_dofs(conn):
    """(k, nloc) node ids -> (k, 3 nloc) DOF ids, node-major."""
    conn = np.asarray(conn, dtype=np.int64)
    return (3 * conn[:, :, None] + np.arange(3)).reshape(len(conn), 3 * conn.shape[1])


class Pattern:
    """CSR pattern over ndof DOFs for a list of node connectivity blocks.

    blocks   list of (k, nloc) int arrays
    After construction: indptr, indices, nnz, and index[b] (k, d, d) for each block b.
    Every block couples all three DOFs of its nodes, so the pattern is that of the node
    pairs with each pair a 3 x 3 block, and is built so: a unique over the node pairs
    (a ninth of the DOF pairs, so a ninth of the sorting). Every node keeps its diagonal
    3 x 3 block, in a block or not.
    """

    def __init__(self, ndof, blocks):
        self.ndof = ndof
        n = ndof // 3
        conns = [np.asarray(b, dtype=np.int64) for b in blocks]
        self.dofs = [block_dofs(b) for b in conns]
        # the node pairs first (a ninth of the DOF pairs), then each as its 3 x 3 block
        diag = np.arange(n, dtype=np.int64)         # every node's block: the DOF diagonal
        rows = np.concatenate([np.repeat(c, c.shape[1], axis=1).ravel() for c in conns] + [diag])
        cols = np.concatenate([np.tile(c, (1, c.shape[1])).ravel() for c in conns] + [diag])
        pairs, inv = np.unique(rows * n + cols, return_inverse=True)
        first, second = pairs // n, pairs % n
        deg = np.bincount(first, minlength=n)
        start = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(deg, out=start[1:])
        # DOF row 3 I + i holds the 3 deg(I) columns 3 J + j of I's neighbours J (sorted):
        # entry (3 I + i, 3 J + j) at 9 start(I) + 3 deg(I) i + 3 pos(I, J) + j
        i3 = np.arange(3)
        base = 9 * start[first] + 3 * (np.arange(len(pairs)) - start[first])   # (P,)
        at = base[:, None, None] + 3 * deg[first][:, None, None] * i3[:, None] + i3  # (P,3,3)
        self.nnz = 9 * len(pairs)
        self.indices = np.empty(self.nnz, dtype=np.int32)
        self.indices[at.ravel()] = np.repeat(3 * second[:, None] + i3, 3, axis=0).ravel()
        self.indptr = np.empty(ndof + 1, dtype=np.int32)
        self.indptr[:-1] = (9 * start[:-1, None] + 3 * deg[:, None] * i3).ravel()
        self.indptr[-1] = self.nnz
        self._keys = np.repeat(np.arange(ndof, dtype=np.int64), np.diff(self.indptr)) * ndof \
            + self.indices
        self.diagonal = self.locate(np.arange(ndof), np.arange(ndof))     # (ndof,) data index
        self.index = []
        offset = 0
        for c in conns:
            k, m = c.shape
            p = inv[offset:offset + k * m * m]
            offset += k * m * m
            self.index.append(at[p].reshape(k, m, m, 3, 3).transpose(0, 1, 3, 2, 4)
                              .reshape(k, 3 * m, 3 * m))

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
