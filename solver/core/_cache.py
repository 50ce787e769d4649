"""Where compiled numba kernels are cached: a user cache directory that survives temporary
folders (an FMU is extracted to a new temporary folder at every start).

numba's own locator files a kernel under a hash of its source file's absolute path, so a
fresh extraction folder would miss the cache every time. The locator below files the
solver's kernels under their module name instead. Its freshness stamp is a hash of the
content of every solver file that defines numba functions (numba's own stamp is the
kernel's file alone): a kernel calls jitted helpers of other files, compiled into it, and
an edit of a helper must recompile its callers too.

Only the solver's own kernels are filed this way: nothing here changes numba's process-wide
configuration (its cache directory, threading layer and vector library stay the process's;
solver.core.numba_config.configure_numba is the explicit call that sets those).

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


def solver_cache_dir():
    """The directory for the solver's compiled kernels: the user cache directory or a
    fallback (module docstring); None when nothing can be written (then the solver's kernels
    are not cached)."""
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
    return wanted


def _impl(caching):
    """numba's cache implementation class (renamed from _CacheImpl to CacheImpl in 0.60)."""
    return getattr(caching, "CacheImpl", None) or caching._CacheImpl


_KERNEL_STAMP = {}


def kernel_sources_stamp(root=None):
    """sha256 (hex) of the content of every .py file under root (default: the solver
    package) that defines numba functions (an @njit decorator), in path order, and of
    whether numba vectorizes with Intel's SVML (other rounding); computed once per root and
    process."""
    root = Path(root or Path(__file__).resolve().parents[1])
    if root not in _KERNEL_STAMP:
        import numba.core.config as config
        digest = hashlib.sha256(b"svml" if getattr(config, "USING_SVML", False) else b"")
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
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(str(CACHE_DIR), "facefmu",
                                            py_func.__module__.rpartition(".")[0])

        def get_source_stamp(self):
            return kernel_sources_stamp()

        @classmethod
        def from_function(cls, py_func, py_file):
            if CACHE_DIR is None or not getattr(py_func, "__module__", "").startswith("solver."):
                return None
            locator = cls(py_func, py_file)
            locator.ensure_cache_path()
            return locator

    if not any(c.__name__ == "StableLocator" for c in _impl(caching)._locator_classes):
        _impl(caching)._locator_classes.insert(0, StableLocator)


def _warm_marker():
    """The file that says this cache holds kernels compiled for the current sources (None
    without a cache)."""
    if CACHE_DIR is None:
        return None
    return Path(CACHE_DIR) / "facefmu" / f"compiled-{kernel_sources_stamp()[:16]}"


def kernels_warm():
    """Whether a process with these kernel sources has run a step with this cache (its
    kernels were then compiled and filed here); False without a cache."""
    marker = _warm_marker()
    return marker is not None and marker.is_file()


def mark_kernels_warm():
    """Note in the cache that these kernel sources have been compiled (after a step)."""
    marker = _warm_marker()
    if marker is not None and not marker.is_file():
        try:
            marker.parent.mkdir(parents=True, exist_ok=True)
            marker.write_text("")
        except OSError:
            pass


def compile_notice():
    """What a user waits for when kernels_warm() is False: a sentence for logs."""
    where = f"cached in {CACHE_DIR}" if CACHE_DIR is not None else "not cached"
    return ("first run of these solver kernels here: numba compiles them before the first "
            f"step, on every core at once (half a minute on 2 cores; {where} for later "
            "runs)")


CACHE_DIR = solver_cache_dir()
_install_stable_locator()
