"""The package's optional dependencies (its pyproject extras), imported where needed.

    extra     installs                  for
    plot      matplotlib                pictures: solver.app.plot, `facefmu run`'s PNG,
                                        `facefmu anatomy --png`
    export    meshio, h5py              VTU and XDMF files (XDMF's data in HDF5): solver.app.io,
                                        `facefmu run --vtu`, `facefmu anatomy --export`
    sweep     dask[distributed], tqdm   parallel runs (solver.sweep), progress bars
    pardiso   pypardiso                 MKL PARDISO (solver.core.linsolve: `auto` takes it where
                                        it imports, else SuperLU)

The FMU needs none of them: numpy, scipy, numba and pythonfmu are the package's own
dependencies. A missing extra raises MissingExtra, whose message names it.
"""

import importlib


class MissingExtra(ImportError):
    """An optional dependency is not installed; the message names the extra."""


def need(module, extra, what):
    """The module `module` (dotted name), imported; MissingExtra naming `extra` where it
    does not import. what: what needs it (for the message)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtra(f"{what} needs {module.split('.')[0]}, which the package's "
                           f"extra '{extra}' installs: pip install \"facefmu[{extra}]\"") \
            from exc
