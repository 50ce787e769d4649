"""Where compiled numba kernels are cached: a user cache directory that survives temporary
folders (an FMU is extracted to a new temporary folder at every start).

numba's own locator files a kernel under a hash of its source file's absolute path, so a
fresh extraction folder would miss the cache every time. The locator below files the
solver's kernels under their module name instead. Its freshness stamp is a hash of the
content of every solver file that defines numba functions (numba's own stamp is the
kernel's file alone): a kernel calls jitted helpers of other files, compiled into it, and
an edit of a helper must recompile its callers too.

Order: $NUMBA_CACHE_DIR if set, else $FACEFMU_CACHE_DIR/numba, else
$XDG_CACHE_HOME/facefmu/numba, else ~/.cache/facefmu/numba. A directory that cannot be
written (read-only, a path through a file, no home) falls back, with a RuntimeWarning, to
a per-user folder of the temporary directory (facefmu-numba-<uid>, mode 0700, used only
when it is ours and nobody else can write it: numba's cache files are pickles), which
later starts reuse; failing that, to a fresh private temporary folder; and when no folder
can be written at all, the solver's kernels are not cached (they compile at every start).
Nothing fails.
"""

import hashlib
import os
import stat
import tempfile
import warnings
from pathlib import Path

# Before numba is imported: numba uses Intel's SVML for vectorized math calls when it
# finds the library (MKL's dependencies bring one), so the kernels' rounding would depend
# on what the process has loaded; without it they are the same everywhere.
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
    except (OSError, ValueError):
        return False


def _owned_private_dir(path: Path) -> bool:
    """path is a real directory (not a link) of this user that nobody else can write."""
    st = os.lstat(path)
    mine = not hasattr(os, "getuid") or st.st_uid == os.getuid()
    return stat.S_ISDIR(st.st_mode) and mine and not st.st_mode & 0o022


def _fallback_dir():
    """A writable private folder of the temporary directory, or None."""
    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    try:
        shared = Path(tempfile.gettempdir()) / f"facefmu-numba-{user}"
        shared.mkdir(mode=0o700, exist_ok=True)
        if _owned_private_dir(shared) and _writable(shared):
            return shared
    except OSError:
        pass
    try:
        return Path(tempfile.mkdtemp(prefix="facefmu-numba-"))
    except OSError:
        return None


def _disable_solver_caching():
    """njit(cache=True) of the solver's kernels then compiles without a cache (numba would
    otherwise refuse a cached function that no locator can place)."""
    from numba.core.dispatcher import Dispatcher
    if getattr(Dispatcher.enable_caching, "_facefmu", False):
        return
    original = Dispatcher.enable_caching

    def enable_caching(self):
        if getattr(self.py_func, "__module__", "").startswith("solver."):
            return
        original(self)
    enable_caching._facefmu = True
    Dispatcher.enable_caching = enable_caching


def configure_numba_cache():
    """Point numba's cache at the user cache directory (or a fallback, see the module
    docstring); call before compiling kernels. The directory used, or None (no cache)."""
    try:
        wanted = Path(os.environ.get("NUMBA_CACHE_DIR") or user_cache_dir() / "numba")
        what = f"numba cache directory {wanted} is not writable"
    except (RuntimeError, KeyError):                # Path.home(): no home directory
        wanted, what = None, "no home directory for the numba cache"
    if wanted is None or not _writable(wanted):
        fallback = _fallback_dir()
        if fallback is None:
            warnings.warn(f"{what} and no temporary folder is writable: the solver's "
                          "kernels compile at every start", RuntimeWarning, stacklevel=2)
            _disable_solver_caching()
            return None
        warnings.warn(f"{what}; compiled kernels go to {fallback}", RuntimeWarning,
                      stacklevel=2)
        wanted = fallback
    os.environ["NUMBA_CACHE_DIR"] = str(wanted)
    import numba.core.config as config
    config.CACHE_DIR = str(wanted)
    return wanted


def _impl(caching):
    """numba's cache implementation class (renamed from _CacheImpl to CacheImpl in 0.60)."""
    return getattr(caching, "CacheImpl", None) or caching._CacheImpl


_KERNEL_STAMP = {}


def kernel_sources_stamp(root=None):
    """sha256 (hex) of the content of every .py file under root (default: the solver
    package) that defines numba functions (an @njit decorator), in path order;
    computed once per root and process."""
    root = Path(root or Path(__file__).resolve().parents[1])
    if root not in _KERNEL_STAMP:
        digest = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            data = path.read_bytes()
            if b"@njit" in data:
                digest.update(str(path.relative_to(root)).encode() + b"\0" + data + b"\0")
        _KERNEL_STAMP[root] = digest.hexdigest()
    return _KERNEL_STAMP[root]


def _install_stable_locator():
    from numba.core import caching

    class StableLocator(caching.UserProvidedCacheLocator):
        """Kernels of the `solver` package, filed by module name under the cache dir."""

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            import numba.core.config as config
            self._cache_path = os.path.join(config.CACHE_DIR, "facefmu",
                                            py_func.__module__.rpartition(".")[0])

        def get_source_stamp(self):
            return kernel_sources_stamp()

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
