"""Where compiled numba kernels are cached: a user cache directory that survives temporary
folders (an FMU is extracted to a new temporary folder at every start).

numba's own locator files a kernel under a hash of its source file's absolute path, so a
fresh extraction folder would miss the cache every time. The locator below files the
solver's kernels under their module name instead; numba's freshness check (a hash of the
source file's content) still recompiles them when the code changes.

Order: $NUMBA_CACHE_DIR if set, else $FACEFMU_CACHE_DIR/numba, else
$XDG_CACHE_HOME/facefmu/numba, else ~/.cache/facefmu/numba. A directory that cannot be
written falls back to a fresh temporary directory, with a warning: kernels then compile
again at each start, nothing fails.
"""

import os
import tempfile
import warnings
from pathlib import Path

# Before numba is imported: numba loads Intel's SVML when it finds it (MKL's dependencies
# bring one); imported inside an FMU beside MKL this corrupted the heap of fmpy's process
# ("corrupted double-linked list" at exit). SVML only speeds up vectorized math calls.
os.environ.setdefault("NUMBA_DISABLE_INTEL_SVML", "1")


def user_cache_dir() -> Path:
    """The FaceFMU cache root (numba kernels, trained reduced models)."""
    if os.environ.get("FACEFMU_CACHE_DIR"):
        return Path(os.environ["FACEFMU_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "facefmu"


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".probe-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
        return True
    except OSError:
        return False


def configure_numba_cache() -> Path:
    """Point numba's cache at the user cache directory; call before compiling kernels."""
    wanted = Path(os.environ.get("NUMBA_CACHE_DIR") or user_cache_dir() / "numba")
    if not _writable(wanted):
        fallback = Path(tempfile.mkdtemp(prefix="facefmu-numba-"))
        warnings.warn(f"numba cache directory {wanted} is not writable; compiled kernels "
                      f"go to {fallback} and will not be reused", RuntimeWarning, stacklevel=2)
        wanted = fallback
    os.environ["NUMBA_CACHE_DIR"] = str(wanted)
    import numba.core.config as config
    config.CACHE_DIR = str(wanted)
    return wanted


def _impl(caching):
    """numba's cache implementation class (renamed from _CacheImpl to CacheImpl in 0.60)."""
    return getattr(caching, "CacheImpl", None) or caching._CacheImpl


def _install_stable_locator():
    from numba.core import caching

    class StableLocator(caching.UserProvidedCacheLocator):
        """Kernels of the `solver` package, filed by module name under the cache dir."""

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            import numba.core.config as config
            self._cache_path = os.path.join(config.CACHE_DIR, "facefmu",
                                            py_func.__module__.rpartition(".")[0])

        @classmethod
        def from_function(cls, py_func, py_file):
            if not getattr(py_func, "__module__", "").startswith("solver."):
                return None
            return super().from_function(py_func, py_file)

    if not any(c.__name__ == "StableLocator" for c in _impl(caching)._locator_classes):
        _impl(caching)._locator_classes.insert(0, StableLocator)


def configure_threading_layer():
    """numba's 'workqueue' threading layer unless the user chose one: the TBB and OpenMP
    layers load a second threading runtime beside MKL's (PARDISO) and the process then
    aborts at exit ("corrupted double-linked list", seen through fmpy). Our kernels hold
    the GIL, so workqueue's lack of thread safety never bites; assembly is as fast."""
    if not os.environ.get("NUMBA_THREADING_LAYER"):
        import numba.core.config as config
        config.THREADING_LAYER = "workqueue"


configure_threading_layer()
CACHE_DIR = configure_numba_cache()
_install_stable_locator()
