"""numba's process-wide settings for the solver, made by one explicit call.

``configure_numba()`` is called by the FMU slave and the command line before the first
kernel runs, and by programs that load the FMU into a process that also runs the solver:

* threading layer ``workqueue`` (unless $NUMBA_THREADING_LAYER names one): the TBB and
  OpenMP layers load a second threading runtime beside MKL's (PARDISO), and the process
  then aborts at exit ("corrupted double-linked list", seen through fmpy). The solver's
  kernels hold the GIL, so workqueue's lack of thread safety never bites; assembly is as
  fast;
* no Intel SVML (unless $NUMBA_DISABLE_INTEL_SVML says otherwise): numba vectorizes math
  calls with SVML when it finds the library (MKL's dependencies can bring one), so the
  kernels' rounding would depend on what the process has loaded. This one takes effect
  only before numba is first imported (``import solver`` does not import it).

Importing this module imports nothing but the standard library. Where the cache of the
solver's compiled kernels lives is not a process-wide setting: solver.core._cache.
"""

import os
import sys
import warnings

THREADING_LAYER = "workqueue"


def configure_numba():
    """Set numba's threading layer and SVML use for this process (module docstring).

    Returns {"threading_layer": name wanted, "svml": bool or None (numba not imported
    yet: off once it is)}. Warns (RuntimeWarning) when numba has already launched another
    threading layer or loaded SVML: those cannot change in a running process."""
    os.environ.setdefault("NUMBA_DISABLE_INTEL_SVML", "1")
    layer = os.environ.setdefault("NUMBA_THREADING_LAYER", THREADING_LAYER)
    if "numba" not in sys.modules:
        return {"threading_layer": layer, "svml": None}
    from numba.core import config
    from numba.np.ufunc import parallel
    config.THREADING_LAYER = layer
    if parallel._is_initialized and parallel.threading_layer() != layer:
        warnings.warn(f"numba already runs its {parallel.threading_layer()!r} threading "
                      f"layer, not {layer!r}: call solver.configure_numba() before the "
                      "first kernel runs", RuntimeWarning, stacklevel=2)
    if config.USING_SVML and os.environ["NUMBA_DISABLE_INTEL_SVML"] not in ("", "0"):
        warnings.warn("numba was imported with Intel SVML on: call solver.configure_numba()"
                      " before importing numba", RuntimeWarning, stacklevel=2)
    return {"threading_layer": layer, "svml": bool(config.USING_SVML)}
