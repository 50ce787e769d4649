"""Sparse direct solvers behind one interface: factorize once, solve many right-hand sides.

``superlu``  scipy.sparse.linalg.splu (always available)
``pardiso``  Intel MKL PARDISO through pypardiso (x86_64 wheels on PyPI), symmetric
``auto``     the fastest available, by benchmarks/linear_solvers.py on this project's
             matrices: pardiso where importable, else superlu.
"""

import os

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .errors import ParameterError

# One MKL thread unless the user asks otherwise, set before pypardiso loads MKL: as fast
# here on 2 cores (0.30 s against 0.53 s for a face factorization), and MKL's OpenMP
# runtime made an FMU host (fmpy) abort at exit.
os.environ.setdefault("MKL_NUM_THREADS", "1")


class SuperLU:
    name = "superlu"

    def factorize(self, K):
        """Symmetric ordering without pivoting (our tangents are symmetric, and pivoting
        multiplied the fill by 30 on compressed states); COLAMD with pivoting as fallback."""
        K = sp.csc_matrix(K)
        try:
            self._lu = sla.splu(K, permc_spec="MMD_AT_PLUS_A",
                                options={"SymmetricMode": True, "DiagPivotThresh": 0.0})
        except RuntimeError:
            self._lu = sla.splu(K, permc_spec="COLAMD")

    def solve(self, b):
        return self._lu.solve(b)


class Pardiso:
    """MKL PARDISO, real symmetric indefinite (mtype -2) on the upper triangle; the
    symbolic analysis (ordering) is done once per sparsity pattern and reused."""

    name = "pardiso"

    def __init__(self):
        import pypardiso
        self._p = pypardiso.PyPardisoSolver(mtype=-2)
        self._pattern = None
        self._U = None

    def _phase(self, phase, b):
        self._p.set_phase(phase)
        return self._p._call_pardiso(self._U, b)

    def factorize(self, K):
        U = sp.triu(sp.csr_matrix(K), format="csr")
        U.sort_indices()
        self._U = U
        if not np.all(np.diff(U.indptr)):
            raise RuntimeError("matrix is singular: an empty row")
        key = (U.shape[0], U.nnz, hash(U.indptr.tobytes()), hash(U.indices.tobytes()))
        zero = np.zeros((U.shape[0], 1))
        if key != self._pattern:
            self._phase(11, zero)
            self._pattern = key
        self._phase(22, zero)

    def solve(self, b):
        return self._phase(33, np.asarray(b, dtype=np.float64))

    def release(self):
        """Free the factorization's memory (phase 0; MKL frees the rest at exit, and
        freeing it twice with phase -1 corrupted the heap)."""
        if self._pattern is not None:
            self._p.free_memory(everything=False)
            self._pattern, self._U = None, None

    def __del__(self):
        try:
            self.release()
        except Exception:
            pass


def available():
    """Names of the solvers that import here."""
    names = ["superlu"]
    try:
        import pypardiso  # noqa: F401
        names.insert(0, "pardiso")
    except ImportError:
        pass
    return names


def make_solver(name="auto"):
    if name == "auto":
        name = available()[0]
    if name == "superlu":
        return SuperLU()
    if name == "pardiso":
        if "pardiso" not in available():
            raise ParameterError("linear solver 'pardiso' needs the package pypardiso")
        return Pardiso()
    raise ParameterError(f"linear solver {name!r} is not one of ['auto', 'pardiso', 'superlu']")
