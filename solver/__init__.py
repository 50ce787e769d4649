"""FaceFMU's standalone finite-element solver.

Units everywhere: mm, N, MPa, s, tonne/mm^3 (see solver.units).

    import solver
    sim = solver.open_simulation("rounding_u", fidelity="balanced")   # a scene's run
    sim.set_activations({"OOP": 0.6}); sim.step(0.01); sim.outputs()

    mesh = solver.Mesh(nodes, bricks)                                 # the FE core alone
    model = solver.Model(mesh, solver.MooneyRivlin(c10=2.5e-3, c20=1.175e-3, d=0.8))
    model.fix(ids); model.prescribe(ids, displacement=(0, 0, -4))
    res = model.solve_static()
"""

from . import _cache  # noqa: F401  (numba cache directory, before any kernel compiles)
from .entry import open_simulation
from .errors import (FaceFMUError, MeshError, MeshFileError,
                     ParameterError)
from .face import FaceModel
from .materials import MooneyRivlin
from .mesh import Mesh
from .model import Model, StaticResult
from .newton import NewtonOptions
from .rom.store import ModelNotTrained
from .scene import Scene, SceneError, load_scene
from .simulation import Simulation

__version__ = "0.1.0"

__all__ = ["open_simulation", "Simulation", "Scene", "load_scene", "FaceModel", "Model",
           "StaticResult", "Mesh", "MooneyRivlin", "NewtonOptions", "FaceFMUError",
           "MeshError", "MeshFileError", "ParameterError", "SceneError", "ModelNotTrained"]
