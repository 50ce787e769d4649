"""Named fidelity presets: what a run trades between accuracy and time.

    Simulation("rounding_u", fidelity="balanced")       # the API
    facefmu run rounding_u --fidelity fast              # the command line
    [scene] fidelity = "fast"                           # a scene file
    fidelity = "accurate"                               # the FMU's String parameter

A preset replaces the numerical fields of a scene: the mesh level (of the generic face; an
ANSYS face keeps its own mesh), half face, substep error tolerance and largest substep,
Newton tolerance and element formulation. The model itself (anatomy, muscles, effects such
as stiffening and contact, schedules, outputs) stays the scene's. Where several settings
meet, the most specific wins: keyword overrides of Simulation (and the command line's
--level, --full) over the preset given to Simulation, that preset over the scene file,
and in a scene file its own keys over its [scene] fidelity.

The presets are the points of the Pareto front (largest error over time in lip aperture
and protrusion against CPU time) measured by `python benchmarks/accuracy_vs_time.py
--duration 0.05`: a lip gesture with contact, its first 0.05 s, against the fine half face
at tight tolerances (docs/accuracy.md):

    preset    mesh, DOF            error aperture / protrusion   real-time factor (CPU)
    fast      coarse half, 3108    0.174 / 0.196 mm              57
    balanced  medium half, 6300    0.113 / 0.013 mm              115
    accurate  fine half, 50925     0.004 / 0.001 mm              3759  (time stepping only)

On that front: the half face (the full face gives the same lip outputs at about twice the
cost), loose tolerances (at every level the mesh error dwarfs the time-stepping and Newton
error, 0.004 mm), mean dilatation ("full" locks: 4 to 7 times the error). The paper level
is off it: its error against fine (0.18 mm) is larger than medium's.
"""

from .errors import ParameterError

LOOSE = dict(substep_tol=1e-2, max_substep=1e-2, newton_rtol=1e-4)
DEFAULTS = dict(substep_tol=1e-3, max_substep=5e-3, newton_rtol=1e-6)

PRESETS = {
    "fast": dict(level="coarse", half=True, formulation="mean_dilatation", **LOOSE),
    "balanced": dict(level="medium", half=True, formulation="mean_dilatation", **LOOSE),
    "accurate": dict(level="fine", half=True, formulation="mean_dilatation", **DEFAULTS),
}
FIDELITIES = tuple(PRESETS)

# --- reduced-order fidelities (solver.rom; issue 10) -----------------------------------
# Not presets of the full-order solver (not in FIDELITIES nor PRESETS): Simulation(...,
# fidelity="realtime") builds a solver.rom.simulation.ReducedSimulation, whose full-order
# model (training snapshots, fallback) has these knobs. Scene files do not take them.
REDUCED = {"realtime": dict(level="coarse", half=True, formulation="mean_dilatation",
                            **LOOSE)}


def fidelity_overrides(name):
    """The Scene fields of the preset `name` (a new dict); ParameterError if unknown."""
    if name in REDUCED:
        return dict(REDUCED[name])
    if name not in PRESETS:
        raise ParameterError(f"fidelity {name!r} is not one of "
                             f"{', '.join(FIDELITIES + tuple(REDUCED))}")
    return dict(PRESETS[name])


def apply_fidelity(scene, name):
    """A new Scene: `scene` (solver.scene.Scene) with the preset `name`'s fields."""
    return scene.with_overrides(**fidelity_overrides(name))
