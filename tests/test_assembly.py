"""The sparsity pattern and the scatter of element blocks into it (solver.core.assembly)."""

import numpy as np

from solver.core.assembly import Assembly, Pattern


def test_pattern_holds_exactly_the_blocks_couplings_and_indexes_them(rng):
    """CSR rows sorted, every block's DOF pairs present and indexed where they are, no
    other entry but the nodes' own 3 x 3 blocks (node 11 is in no block)."""
    n = 12
    blocks = [rng.integers(0, 11, size=(7, 4)), rng.integers(0, 11, size=(5, 2)),
              np.array([[3], [5]])]
    pat = Pattern(3 * n, blocks)
    want = np.zeros((3 * n, 3 * n), dtype=bool)
    for node in range(n):
        want[3 * node:3 * node + 3, 3 * node:3 * node + 3] = True
    for b in blocks:
        for conn in b:
            dofs = (3 * conn[:, None] + np.arange(3)).ravel()
            want[np.ix_(dofs, dofs)] = True
    got = pat.matrix(np.ones(pat.nnz)).toarray() != 0
    assert np.array_equal(got, want) and pat.nnz == want.sum()
    rows = np.repeat(np.arange(3 * n), np.diff(pat.indptr))
    assert np.all(np.diff(rows * 3 * n + pat.indices) > 0)             # sorted, unique
    for dofs, index in zip(pat.dofs, pat.index):
        assert np.array_equal(rows[index], np.broadcast_to(dofs[:, :, None], index.shape))
        assert np.array_equal(pat.indices[index], np.broadcast_to(dofs[:, None, :],
                                                                    index.shape))
    assert np.array_equal(rows[pat.diagonal], np.arange(3 * n))
    assert np.array_equal(pat.indices[pat.diagonal], np.arange(3 * n))


def test_scattered_blocks_sum_to_the_dense_assembly(rng):
    """Element matrices and vectors scattered into the pattern give the dense sums."""
    n = 9
    conn = rng.integers(0, n, size=(6, 3))
    conn = conn[[len(set(c)) == 3 for c in conn]]
    pat = Pattern(3 * n, [conn])
    ke = rng.normal(size=(len(conn), 9, 9))
    fe = rng.normal(size=(len(conn), 9))
    asm = Assembly(pat, True)
    asm.add_block(0, fe, ke)
    K, f = np.zeros((3 * n, 3 * n)), np.zeros(3 * n)
    for c, k, v in zip(conn, ke, fe):
        dofs = (3 * c[:, None] + np.arange(3)).ravel()
        K[np.ix_(dofs, dofs)] += k
        f[dofs] += v
    assert np.allclose(asm.matrix().toarray(), K, atol=1e-13)
    assert np.allclose(asm.residual, f, atol=1e-13)
