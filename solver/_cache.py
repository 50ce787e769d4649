"""Where compiled numba kernels are cached: a user cache directory that survives temporary
folders (an FMU is extracted to a new temporary folder at every start).

Order: $NUMBA_CACHE_DIR if set, else $FACEFMU_CACHE_DIR/numba, else
$XDG_CACHE_HOME/facefmu/numba, else ~/.cache/facefmu/numba. A directory that cannot be
written falls back to a fresh temporary directory, with a warning: kernels then compile
again at each start, nothing fails.
"""

import os
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


CACHE_DIR = configure_numba_cache()
