"""Sparse direct solvers behind one interface: factorize once, solve many right-hand sides.

``superlu``  scipy.sparse.linalg.splu (always available)
``pardiso``  Intel MKL PARDISO through pypardiso (x86_64 wheels on PyPI)
``auto``     the fastest available, by benchmarks/linear_solvers.py on this project's
             matrices: pardiso where importable, else superlu.
"""

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .errors import ParameterError


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
    name = "pardiso"

    def __init__(self):
        import pypardiso
        self._solver = pypardiso.PyPardisoSolver()
        self._K = None

    def factorize(self, K):
        self._K = sp.csr_matrix(K)
        self._K.sort_indices()
        self._solver.factorize(self._K)

    def solve(self, b):
        return self._solver.solve(self._K, np.asarray(b, dtype=np.float64))


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
