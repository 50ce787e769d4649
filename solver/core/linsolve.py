"""Sparse direct solvers behind one interface: factorize once, solve many right-hand sides.

``superlu``  scipy.sparse.linalg.splu (always available)
``pardiso``  Intel MKL PARDISO through pypardiso (x86_64 wheels on PyPI), symmetric
``pardiso-single``  the same, factorized and solved in single precision (Pardiso's
             docstring: Newton's residual stays in double)
``auto``     the fastest available, by benchmarks/solver_scaling.py and
             benchmarks/fast_path.py on this project's matrices: pardiso-single where
             pypardiso imports, else superlu.

Reuse: a solver counts its factorizations and keeps a tag of what its current one was
made for (``refactor(K, tag)``; ``tag`` None: no valid factorization), so that Newton
(solver.core.newton, ``NewtonOptions.reuse``) can solve with the factorization of an earlier
tangent as long as that converges fast enough.

BLAS threads: ``single_threaded_blas()`` runs a block with every OpenBLAS loaded in the
process at one thread (threadpoolctl) and restores the caller's setting after. OpenBLAS
threads its level-1 routines above about 10^4 entries, so numpy's dot products and norms
of Newton's vectors would run on several threads, which then compete with numba's workers
(and any other process) for the cores: on a loaded machine a threaded dot product of
Newton's size waits for its threads far longer than it computes.
"""

import contextlib
import ctypes
import os

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from solver.core.errors import ParameterError


def _cpus():
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                  # not on Linux
        return os.cpu_count() or 1


# MKL (PARDISO) threads: one per CPU this process may run on, unless the user (or a host:
# dask's nanny sets one thread per sweep worker) chose; set before pypardiso loads MKL.
# PARDISO gains from every core it gets (benchmarks/fast_path.py at MKL_NUM_THREADS=2
# against 1; docs/dev-notes/fast_path.md). The FMU's slave runs the scene's solver too.
os.environ.setdefault("MKL_NUM_THREADS", str(_cpus()))
# MKL's OpenMP threads go to sleep as soon as a PARDISO call ends (KMP_BLOCKTIME=0; Intel's
# default spins for 200 ms), so that they do not take the cores from the numba kernels
# that run right after a solve (docs/dev-notes/fast_path.md).
os.environ.setdefault("KMP_BLOCKTIME", "0")


def _openblas():
    """threadpoolctl's controller of the OpenBLAS libraries loaded in this process (numpy's
    and scipy's), made at the first call. MKL is left alone: PARDISO gains from every core."""
    global _OPENBLAS
    if _OPENBLAS is None:
        from threadpoolctl import ThreadpoolController
        _OPENBLAS = ThreadpoolController().select(internal_api="openblas")
    return _OPENBLAS


_OPENBLAS = None


@contextlib.contextmanager
def single_threaded_blas():
    """Run the block with one OpenBLAS thread; the caller's thread counts after."""
    with _openblas().limit(limits=1):
        yield


class _Reusable:
    """Counting and tagging of factorizations, shared by the solvers, and what Newton
    records about them:

    notes           {name: value} about the current factorization, emptied by every
                    refactor and invalidate: "plain" (r, A^-1 (-r_f)) Newton's last plain
                    direction; "contact_status" the contact status it holds
                    (solver.core.contact_update); "krylov_base" the contact tangent it
                    holds and GMRES's recycled solves (solver.core.krylov)
    smooth_tangent  (tag, CSR data, u) the part without nonsmooth terms of the last full
                    assembly, for Newton's partial refreshes; None after invalidate
    """

    factorizations = 0          # how many factorize() calls so far
    tag = None                  # what the current factorization was made for (None: none)
    smooth_tangent = None

    @property
    def notes(self):
        if "_notes" not in self.__dict__:
            self._notes = {}
        return self._notes

    def refactor(self, K, tag):
        """Factorize K and remember tag (what it was made for: Newton's (reduction, key))."""
        self.tag = None
        self.notes.clear()
        self.factorize(K)
        self.factorizations += 1
        self.tag = tag

    def invalidate(self):
        """Forget the current factorization (the next Newton iteration makes a new one)."""
        self.tag = None
        self.notes.clear()
        self.smooth_tangent = None


class SuperLU(_Reusable):
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


# PARDISO's parameters (1-based iparm, MKL's manual), mtype -2. iparm(1) = 1: ours, not
# MKL's defaults (pypardiso leaves iparm(1) = 0, under which MKL ignores every other entry).
# MKL's defaults pivot 1x1 and 2x2 (Bunch-Kaufman, iparm(21) = 1) and then refine every
# solution twice: three solves and two products with K for each Newton direction, which
# modified Newton pays at every iteration (a reused factorization is refined against its
# own matrix, so the refinement buys nothing there). 1x1 diagonal pivoting refines only
# after a perturbed pivot (iparm(8) = 0): one solve per direction, factorizations as fast,
# the relative residual of the same order (1e-13) on the face's tangents.
# benchmarks/solver_scaling.py times factorization and solve apart (docs/benchmarks.md);
# figures of the whole gesture in docs/dev-notes/fast_path.md.
# A single-precision factorization whose first solve leaves ||K x - b|| above this times
# ||b|| is made again in double (case b's tangents: about 6e-5).
SINGLE_CHECK = 1e-3
IPARM = {1: 1,          # use the entries below
         2: 2,          # fill-in reducing ordering: METIS nested dissection
         8: 0,          # iterative refinement: two steps, only after perturbed pivots
         10: 8,         # pivot perturbation 1e-8
         11: 0, 13: 0,  # no scaling, no weighted matching (symmetric matrices)
         18: -1,        # report the factor's nonzeros (iparm(18))
         21: 0}         # 1x1 diagonal pivoting


def _mkl_threads():
    try:
        return max(int(os.environ["MKL_NUM_THREADS"]), 1)
    except (KeyError, ValueError):
        return _cpus()


class _Handle:
    """One PARDISO instance (pypardiso's loader and handle; its ctypes entry point called
    directly, with the index arrays converted once per pattern instead of at every call)
    in double or single precision (iparm(28) = 1: the matrix, the right-hand sides and the
    solutions in float32). Conditional numerical reproducibility (iparm(34), MKL's thread
    count): the same matrix factorizes to the same bits every time. Without it a single
    factorization of the same tangent, made again on the same handle, can give solutions
    that differ in the fifth digit (double: the thirteenth), so that a step repeated from
    the same state (solver.core.transient: an FMU rollback) would not repeat exactly."""

    def __init__(self, single):
        pypardiso = _pypardiso()
        self.p = pypardiso.PyPardisoSolver(mtype=-2)
        for i, value in IPARM.items():
            self.p.set_iparm(i, value)
        self.p.set_iparm(28, 1 if single else 0)
        self.p.set_iparm(34, _mkl_threads())    # conditional numerical reproducibility
        self.dtype = np.float32 if single else np.float64
        self.pattern = None         # the key of the analysed pattern
        self.ia = self.ja = None    # its 1-based int32 index arrays
        self.a = None               # the factorized values, in dtype

    def _args(self, phase, n, b, x, err):
        """The ctypes arguments of one PARDISO call on b (in) and x (out)."""
        p = self.p
        i32 = ctypes.POINTER(ctypes.c_int32)
        return (p.pt.ctypes.data_as(ctypes.POINTER(p._pt_type[0])),
                ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(1)),
                ctypes.byref(ctypes.c_int32(-2)), ctypes.byref(ctypes.c_int32(phase)),
                ctypes.byref(ctypes.c_int32(n)), self.a.ctypes.data_as(ctypes.c_void_p),
                self.ia.ctypes.data_as(i32), self.ja.ctypes.data_as(i32),
                p.perm.ctypes.data_as(i32),
                ctypes.byref(ctypes.c_int32(1 if b.ndim == 1 else b.shape[1])),
                p.iparm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(0)),
                b.ctypes.data_as(ctypes.c_void_p), x.ctypes.data_as(ctypes.c_void_p),
                ctypes.byref(err))

    def call(self, phase, n, b):
        b = np.asfortranarray(b, dtype=self.dtype)
        x = np.zeros_like(b)
        err = ctypes.c_int32(0)
        self.p._mkl_pardiso(*self._args(phase, n, b, x, err))
        if err.value != 0:
            raise RuntimeError(f"PARDISO error {err.value} in phase {phase}")
        return np.ascontiguousarray(x, dtype=np.float64)

    def factorize(self, U, key):
        """Analyse U's pattern where it is new (phase 11), then factorize (phase 22).
        The arguments of the call that frees it (phase 0) are made now, with the arrays
        they point to kept: release() then calls MKL through ctypes alone, as it must
        when the interpreter shuts down (numpy's .ctypes imports a module on first use,
        and imports fail then)."""
        n = U.shape[0]
        self.a = U.data.astype(self.dtype)
        if key != self.pattern:
            self.ia = (U.indptr + 1).astype(np.int32)
            self.ja = (U.indices + 1).astype(np.int32)
            self.call(11, n, np.zeros(n))
            self.pattern = key
        self.call(22, n, np.zeros(n))
        b, x = np.zeros(n, dtype=self.dtype), np.zeros(n, dtype=self.dtype)
        self._free = (self._args(0, n, b, x, ctypes.c_int32(0)), self.a, self.ia, self.ja,
                      b, x)

    @property
    def perturbed(self):
        """Pivots perturbed by the last factorization (iparm(14))."""
        return int(self.p.iparm[13])

    def release(self):
        """Free the factorization (phase 0) with the arguments made at factorize: no
        scipy, no numpy, no import, so that it also works while the interpreter shuts
        down (a master that terminates the FMU from its own teardown: libcosim's)."""
        if self.pattern is not None:
            self.p._mkl_pardiso(*self._free[0])
            self.pattern = None


class Pardiso(_Reusable):
    """MKL PARDISO, real symmetric indefinite (mtype -2) on the upper triangle; the
    symbolic analysis (ordering) is done once per sparsity pattern and reused, and so is
    the gather of the upper triangle from K's CSR data when K comes with the same index
    arrays (as solver.core.assembly.Reduction.matrix gives them).

    precision "double", or "single": the factorization and the solves in float32 (the
    right-hand side and the solution converted), faster to factorize and to solve
    (docs/benchmarks.md); the solution's relative residual ||K x - b|| / ||b|| is then about
    1e-5 to 1e-4 instead of 1e-13 (case b's tangent, docs/dev-notes/fast_path.md). Newton's residual
    stays in double, so the converged state is that of the double solver to the Newton
    tolerance; a direction only converges a little less. A single factorization falls back
    to double (the factorization made again, counted as one) where it perturbed a pivot,
    or where the first solve with it leaves a relative residual above SINGLE_CHECK."""

    def __init__(self, precision="double"):
        if precision not in ("double", "single"):
            raise ParameterError(f"precision {precision!r} is not 'double' or 'single'")
        self.precision = precision
        self.name = "pardiso-single" if precision == "single" else "pardiso"
        self._handles = {}
        self._U = None
        self._K = None              # the matrix of a single factorization, until checked
        self._source = None         # (shape, indptr, indices) of the K the gather was made for
        self._upper = None          # data indices of K's upper triangle, in U's order
        self._key = None            # the pattern key of the current factorization
        self._active = None         # the handle holding the current factorization
        self.fallbacks = 0          # single factorizations redone in double

    def _handle(self, single):
        if single not in self._handles:
            self._handles[single] = _Handle(single)
        return self._handles[single]

    def _same_pattern(self, K):
        src = self._source
        return src is not None and K.shape == src[0] and np.array_equal(K.indptr, src[1]) \
            and np.array_equal(K.indices, src[2])

    def _gather(self, K):
        """U (upper triangle of K, sorted CSR), by the cached gather where K has the
        pattern of the last one; else the gather is built (K's entries numbered, the
        numbers' upper triangle taken)."""
        if self._same_pattern(K):
            self._U.data = K.data[self._upper]
            return self._U
        if not K.has_canonical_format:
            K = K.copy()
            K.sum_duplicates()
        marker = sp.csr_matrix((np.arange(K.nnz, dtype=np.float64) + 1.0, K.indices,
                                K.indptr), shape=K.shape)
        U = sp.triu(marker, format="csr")
        U.sort_indices()
        self._upper = U.data.astype(np.int64) - 1
        U.data = K.data[self._upper]
        self._source = (K.shape, K.indptr.copy(), K.indices.copy())
        return U

    def factorize(self, K):
        K = sp.csr_matrix(K)
        U = self._gather(K)
        self._U = U
        if not np.all(np.diff(U.indptr)):
            raise RuntimeError("matrix is singular: an empty row")
        key = (U.shape[0], U.nnz, hash(U.indptr.tobytes()), hash(U.indices.tobytes()))
        self._key, self._active, self._K = key, None, None
        if self.precision == "single":
            h = self._handle(True)
            h.factorize(U, key)
            if h.perturbed == 0:
                self._active, self._K = h, K
                return
            self.fallbacks += 1
        self._active = self._handle(False)
        self._active.factorize(U, key)

    def solve(self, b):
        """x (n,) or (n, k) for b (n,) or (n, k) (k right-hand sides in one call)."""
        if self._active is None:
            raise RuntimeError("no factorization to solve with")
        b = np.asarray(b, dtype=np.float64)
        x = self._active.call(33, self._U.shape[0], b)
        if self._K is not None:                 # the first solve of a single factorization
            K, self._K = self._K, None
            if np.linalg.norm(K @ x - b) > SINGLE_CHECK * np.linalg.norm(b):
                self.fallbacks += 1
                self._active = self._handle(False)
                self._active.factorize(self._U, self._key)
                x = self._active.call(33, self._U.shape[0], b)
        return x

    def release(self, buffers=True):
        """Free the factorizations' memory (phase 0; MKL frees the rest at exit, and
        freeing it twice with phase -1 corrupted the heap), then, with buffers and where a
        factorization was freed, MKL's pooled buffers (free_mkl_buffers)."""
        held = any(h.pattern is not None for h in self._handles.values())
        for h in self._handles.values():
            h.release()
        self._U, self._source, self._active, self._K = None, None, None, None
        self.tag = None
        if buffers and held:
            free_mkl_buffers()

    def __del__(self):
        try:                    # no call into MKL's memory manager from a finalizer
            self.release(buffers=False)
        except Exception:
            pass


def _pypardiso():
    """The pypardiso module, imported with PYPARDISO_MKL_RT set to the mkl package's
    libmkl_rt where the user did not set it: pypardiso looks the library up by name, which
    fails for a pip install's, and then globs all of sys.prefix for it at its import (and
    for each solver it makes): a slow walk of the whole environment, inside the first step
    of a run."""
    if "PYPARDISO_MKL_RT" not in os.environ:
        from importlib import metadata
        try:
            libs = [f.locate().resolve() for f in metadata.files("mkl") or ()
                    if f.name.startswith(("libmkl_rt", "mkl_rt"))]
        except metadata.PackageNotFoundError:
            libs = []
        libs = sorted((p for p in libs if p.is_file()), key=lambda p: len(str(p)))
        if libs:
            os.environ["PYPARDISO_MKL_RT"] = str(libs[0])
    import pypardiso
    global _MKL_FREE_BUFFERS
    path = os.environ.get("PYPARDISO_MKL_RT")
    if path and _MKL_FREE_BUFFERS is None:     # bound now: callable at shutdown, no import
        try:
            _MKL_FREE_BUFFERS = ctypes.CDLL(path).mkl_free_buffers
        except (OSError, AttributeError):
            pass
    return pypardiso


_MKL_FREE_BUFFERS = None


def free_mkl_buffers():
    """Hand MKL's pooled memory back (mkl_free_buffers: the buffers its memory manager keeps
    for reuse, none in use; later calls allocate again), where this process loaded MKL
    through pypardiso. An FMU's process (fmpy's) with a scene on PARDISO aborted at its
    exit in 6 of 8 runs of three instances each without it (heap corruption reported by
    glibc), in none of 24 with it at the instances' terminate; with twelve instances, in 3
    of 24 (facefmu/facefmu_slave.py)."""
    if _MKL_FREE_BUFFERS is not None:
        _MKL_FREE_BUFFERS()


def available():
    """Names of the solvers that import here, the fastest first."""
    names = ["superlu"]
    try:
        _pypardiso()
        names[:0] = ["pardiso-single", "pardiso"]
    except ImportError:
        pass
    return names


SOLVERS = ("auto", "pardiso-single", "pardiso", "superlu")


def make_solver(name="auto"):
    if name == "auto":
        name = available()[0]
    if name == "superlu":
        return SuperLU()
    if name in ("pardiso", "pardiso-single"):
        if name not in available():
            raise ParameterError(f"linear solver {name!r} needs the package pypardiso")
        return Pardiso("single" if name == "pardiso-single" else "double")
    raise ParameterError(f"linear solver {name!r} is not one of {list(SOLVERS)}")
