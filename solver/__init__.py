"""FaceFMU's standalone finite-element solver.

Units everywhere: mm, N, MPa, s, tonne/mm^3 (see solver.core.units).

    import solver
    solver.configure_numba()        # numba's settings as in the FMU (before the first kernel)
    sim = solver.open_simulation("rounding_u", fidelity="balanced")   # a scene's run
    sim.set_activations({"OOP": 0.6}); sim.step(0.01); sim.outputs()

    mesh = solver.Mesh(nodes, bricks)                                 # the FE core alone
    model = solver.Model(mesh, solver.MooneyRivlin(c10=2.5e-3, c20=1.175e-3, d=0.8))
    model.fix(ids); model.prescribe(ids, displacement=(0, 0, -4))
    res = model.solve_static()
"""

import importlib
from typing import TYPE_CHECKING

from solver.core.numba_config import configure_numba

if TYPE_CHECKING:                    # for readers and type checkers; at run time: __getattr__
    from solver.app.scene import Scene, SceneError, load_scene
    from solver.app.simulation import Simulation
    from solver.core.errors import FaceFMUError, MeshError, MeshFileError, ParameterError
    from solver.core.materials import MooneyRivlin
    from solver.core.mesh import Mesh
    from solver.core.model import Model, StaticResult
    from solver.core.newton import NewtonOptions
    from solver.entry import open_simulation
    from solver.face.face_model import FaceModel
    from solver.rom.store import ModelNotTrained

__version__ = "0.1.0"

_WHERE = {
    "open_simulation": "solver.entry",
    "Simulation": "solver.app.simulation",
    "Scene": "solver.app.scene", "SceneError": "solver.app.scene",
    "load_scene": "solver.app.scene",
    "FaceModel": "solver.face.face_model",
    "Model": "solver.core.model", "StaticResult": "solver.core.model",
    "Mesh": "solver.core.mesh",
    "MooneyRivlin": "solver.core.materials",
    "NewtonOptions": "solver.core.newton",
    "FaceFMUError": "solver.core.errors", "MeshError": "solver.core.errors",
    "MeshFileError": "solver.core.errors", "ParameterError": "solver.core.errors",
    "ModelNotTrained": "solver.rom.store",
}

__all__ = ["configure_numba", *_WHERE]


def __getattr__(name):
    """The entry points, imported on first use: `import solver` alone loads no numba, so
    that configure_numba() can still set what must precede numba's import."""
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'solver' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_WHERE])
