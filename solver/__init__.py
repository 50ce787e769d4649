"""FaceFMU's standalone finite-element solver.

Units everywhere: mm, N, MPa, s, tonne/mm^3 (see solver.units).

    import solver
    mesh = solver.Mesh(nodes, bricks)
    model = solver.Model(mesh, solver.MooneyRivlin(c10=2.5e-3, c20=1.175e-3, d=0.8))
    model.fix(ids); model.prescribe(ids, displacement=(0, 0, -4))
    res = model.solve_static()
"""

from . import _cache  # noqa: F401  (numba cache directory, before any kernel compiles)
from .errors import (FaceFMUError, MeshError, MeshFileError,
                     ParameterError)
from .face import FaceModel
from .materials import MooneyRivlin
from .mesh import Mesh
from .model import Model, StaticResult
from .newton import NewtonOptions

__version__ = "0.1.0"

__all__ = ["FaceModel", "Mesh", "MooneyRivlin", "Model", "StaticResult", "NewtonOptions", "FaceFMUError",
           "MeshError", "MeshFileError", "ParameterError"]
