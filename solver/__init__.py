"""FaceFMU's standalone finite-element solver.

Units everywhere: mm, N, MPa, s, tonne/mm^3 (see solver.core.units).

    import solver
    sim = solver.open_simulation("rounding_u", fidelity="balanced")   # a scene's run
    sim.set_activations({"OOP": 0.6}); sim.step(0.01); sim.outputs()

    mesh = solver.Mesh(nodes, bricks)                                 # the FE core alone
    model = solver.Model(mesh, solver.MooneyRivlin(c10=2.5e-3, c20=1.175e-3, d=0.8))
    model.fix(ids); model.prescribe(ids, displacement=(0, 0, -4))
    res = model.solve_static()
"""

from solver.core import _cache  # noqa: F401  (numba cache directory, before any kernel compiles)
from solver.entry import open_simulation
from solver.core.errors import FaceFMUError, MeshError, MeshFileError, ParameterError
from solver.face.face_model import FaceModel
from solver.core.materials import MooneyRivlin
from solver.core.mesh import Mesh
from solver.core.model import Model, StaticResult
from solver.core.newton import NewtonOptions
from solver.rom.store import ModelNotTrained
from solver.app.scene import Scene, SceneError, load_scene
from solver.app.simulation import Simulation

__version__ = "0.1.0"

__all__ = ["open_simulation", "Simulation", "Scene", "load_scene", "FaceModel", "Model",
           "StaticResult", "Mesh", "MooneyRivlin", "NewtonOptions", "FaceFMUError",
           "MeshError", "MeshFileError", "ParameterError", "SceneError", "ModelNotTrained"]
