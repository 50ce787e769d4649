"""Named fidelity presets: what a run trades between accuracy and time.

    open_simulation("rounding_u", fidelity="balanced")  # the API (solver.entry)
    facefmu run rounding_u --fidelity fast              # the command line
    [scene] fidelity = "fast"                           # a scene file
    fidelity = "accurate"                               # the FMU's String parameter

and, in all four places, "realtime": the reduced-order model of solver.rom (REDUCED
below; docs/realtime.md).

A preset is a set of a scene's numerical fields (PRESETS below: the generic face's mesh
level and brick rows, half face, element formulation, substep and Newton tolerances, the
lip/lip contact's penalty); the model itself (anatomy, muscles, effects, schedules,
outputs) stays the scene's. An ANSYS face keeps its own mesh: level and rows do not
apply to it. Where several settings meet, the most specific wins: keyword overrides of
Simulation (and the command line's --level, --full) over the preset, the preset over the
scene file, and in a scene file its own keys over its [scene] fidelity.

The presets are points of the Pareto front (largest error in lip aperture and protrusion
against CPU time) of `python benchmarks/accuracy_vs_time.py --cost cpu`, each loosened as
far as the mesh error hides the tolerances' and as the contact gesture of
benchmarks/fast_path.py still runs through on the reference face. docs/accuracy.md has
the figures; `python benchmarks/presets_table.py` writes every preset's values to
docs/presets.md.
"""

from solver.core.errors import ParameterError
from solver.face.terms.contact import PENALTY

LOOSE = dict(substep_tol=1e-2, max_substep=1e-2, newton_rtol=1e-4, newton_utol=1e-4)
DEFAULTS = dict(substep_tol=1e-3, max_substep=5e-3, newton_rtol=1e-6, newton_utol=1e-5,
                lip_penalty=PENALTY)
# Newton at 1e-4 on the residual and 1e-2 mm on its last update (a residual tolerance of
# 1e-3 takes benchmarks/fast_path.py's case a to a cutback); the lip penalty stays PENALTY:
# a softer one lets the reference face's lips into each other by more than the 0.05 mm
# contact tolerance of solver.validation.stability under OOP + BUC at 1
NEWTON_LOOSE = dict(newton_rtol=1e-4, newton_utol=1e-2, lip_penalty=PENALTY)
# BDF2 (second order) at substeps of at most the co-simulation's 5 ms; its error estimate
# shortens them where activations jump. The substep tolerances keep each preset's time
# error below its mesh's error against the fine face: on the sweep's gesture `fast` (0.5
# mm) is as close to the fine face as its mesh at the default tolerances, and `balanced`
# (0.1 mm) within 0.01 mm of the paper mesh at 1e-2 mm (docs/accuracy.md); replayed, the
# main job's inputs on the medium mesh stay within 0.21 mm of a tight run at 0.5 mm and
# within 0.07 mm at 0.1 mm (docs/dev-notes/time-integration.md).
STEP_BDF2 = dict(integrator="bdf2", max_substep=5e-3, substep_rtol=0.0)

PRESETS = {
    "fast": dict(level="medium", rows=1, half=True, formulation="mean_dilatation",
                 substep_tol=0.5, **STEP_BDF2, **NEWTON_LOOSE),
    "balanced": dict(level="paper", rows=1, half=True, formulation="mean_dilatation",
                     substep_tol=0.1, **STEP_BDF2, **NEWTON_LOOSE),
    "accurate": dict(level="fine", rows=2, half=True, formulation="mean_dilatation",
                     **dict(DEFAULTS, **STEP_BDF2, substep_tol=1e-2)),
}
FIDELITIES = tuple(PRESETS)

# --- reduced-order fidelities (solver.rom) ----------------------------------------------
# Not presets of the full-order solver (not in FIDELITIES nor PRESETS): open_simulation(...,
# fidelity="realtime") (solver.entry), a scene file's `fidelity = "realtime"`, `facefmu run
# --fidelity realtime` and the FMU's fidelity parameter open a solver.rom.simulation.
# ReducedSimulation, whose full-order model (training snapshots, fallback) has these
# knobs: the coarse generic half face at loose tolerances (a reduced model of the
# balanced mesh: docs/dev-notes/realtime-balanced.md).
REDUCED = {"realtime": dict(level="coarse", half=True, formulation="mean_dilatation",
                            integrator="backward_euler", **LOOSE)}


def fidelity_overrides(name, anatomy="generic"):
    """The Scene fields of the preset `name` (a new dict) for the anatomy source `anatomy`
    (an ANSYS face keeps its own mesh: no level or rows); ParameterError if unknown."""
    if name in REDUCED:
        return dict(REDUCED[name])
    if name not in PRESETS:
        raise ParameterError(f"fidelity {name!r} is not one of "
                             f"{', '.join(FIDELITIES + tuple(REDUCED))}")
    out = dict(PRESETS[name])
    if anatomy != "generic":
        out.pop("rows")
    return out


def apply_fidelity(scene, name):
    """A new Scene: `scene` (solver.app.scene.Scene) with the preset `name`'s fields (its
    `fidelity` field, which makes open_simulation open the reduced model for "realtime",
    is left as it was: the full-order model at the realtime knobs is this scene)."""
    return scene.with_overrides(**fidelity_overrides(name, scene.anatomy))
