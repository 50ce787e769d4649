"""Named fidelity presets: what a run trades between accuracy and time.

    Simulation("rounding_u", fidelity="balanced")       # the API
    facefmu run rounding_u --fidelity fast              # the command line
    [scene] fidelity = "fast"                           # a scene file
    fidelity = "accurate"                               # the FMU's String parameter

and, in all four places, "realtime": the reduced-order model of solver.rom (REDUCED
below; docs/realtime.md).

A preset replaces the numerical fields of a scene: the mesh level (of the generic face; an
ANSYS face keeps its own mesh), half face, substep error tolerance and largest substep,
Newton tolerance and element formulation. The model itself (anatomy, muscles, effects such
as stiffening and contact, schedules, outputs) stays the scene's. Where several settings
meet, the most specific wins: keyword overrides of Simulation (and the command line's
--level, --full) over the preset given to Simulation, that preset over the scene file,
and in a scene file its own keys over its [scene] fidelity.

The presets were picked from the Pareto front (largest error over time in lip aperture
and protrusion against CPU time) of an earlier sweep over 0.05 s; the default sweep of
`python benchmarks/accuracy_vs_time.py` (a 0.1 s lip gesture with contact, against the
fine half face at DEFAULT tolerances; docs/accuracy.md) now measures them as:

    preset    mesh, DOF            error aperture / protrusion   real-time factor (CPU)
    fast      coarse half, 3108    1.13 / 0.39 mm                1517
    balanced  medium half, 6300    0.19 / 0.06 mm                241
    accurate  fine half, 50925     the reference                 6972

On that gesture the coarse level is slower and less accurate than medium, so `fast` is
off the front (not yet explained); the half face gives the full face's lip outputs,
loose tolerances cost little accuracy against the mesh error, and mean dilatation is
needed ("full" locks).
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
# fidelity="realtime"), a scene file's `fidelity = "realtime"`, `facefmu run --fidelity
# realtime` and the FMU's fidelity parameter build a solver.rom.simulation.
# ReducedSimulation, whose full-order model (training snapshots, fallback) has these knobs.
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
    """A new Scene: `scene` (solver.scene.Scene) with the preset `name`'s fields (its
    `fidelity` field, which makes Simulation build the reduced model for "realtime", is
    left as it was: the full-order model at the realtime knobs is this scene)."""
    return scene.with_overrides(**fidelity_overrides(name))
