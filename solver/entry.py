"""open_simulation: a scene's simulation at a fidelity, full or reduced order.

    sim = open_simulation("rounding_u")                        # the scene's own fidelity
    sim = open_simulation("rounding_u", fidelity="fast", level="coarse")
    sim = open_simulation("speech", fidelity="realtime")       # the reduced-order model

A fidelity of solver.app.fidelity.REDUCED ("realtime"), given here or named by the scene file
(`fidelity = "realtime"`), opens a solver.rom.simulation.ReducedSimulation: the scene's
trained reduced model, with the full model as its fallback. Any other opens a
solver.app.simulation.Simulation, the full model. Both have the same runtime API
(set_activations, set_jaw, step, outputs, run, get_state, set_state): the FMU, the
command line and the sweeps open their simulations here.
"""

from solver.app.fidelity import REDUCED
from solver.app.simulation import Simulation, resolve_scene


def is_reduced(scene, fidelity=None):
    """Whether open_simulation(scene, fidelity) opens the reduced model: fidelity, or the
    scene's own where fidelity is None, is one of REDUCED. scene: a Scene, built-in name
    or TOML path."""
    name = fidelity if fidelity is not None else resolve_scene(scene).fidelity
    return name in REDUCED


def open_simulation(scene="default", fidelity=None, **overrides):
    """A simulation of scene (Scene, built-in name or TOML path) at fidelity (a name of
    solver.app.fidelity; None: the scene's own): a ReducedSimulation where is_reduced, else a
    Simulation. overrides: keyword arguments of that class (Scene fields, loaded_anatomy;
    for the reduced model rom_model, rom_dirs, trust, ...)."""
    scene = resolve_scene(scene)
    if is_reduced(scene, fidelity):
        from solver.rom.simulation import ReducedSimulation
        return ReducedSimulation(scene, fidelity=fidelity, **overrides)
    return Simulation(scene, fidelity=fidelity, **overrides)
