"""Named fidelity presets: what a run trades between accuracy and time.

    open_simulation("rounding_u", fidelity="balanced")  # the API (solver.entry)
    facefmu run rounding_u --fidelity fast              # the command line
    [scene] fidelity = "fast"                           # a scene file
    fidelity = "accurate"                               # the FMU's String parameter

and, in all four places, "realtime": the reduced-order model of solver.rom (REDUCED
below; docs/realtime.md).

A preset replaces the numerical fields of a scene: the mesh level (of the generic face; an
ANSYS face keeps its own mesh), half face, substep error tolerance and largest substep,
Newton tolerance, element formulation and the lip/lip contact's penalty. The model
itself (anatomy, muscles, effects such as stiffening and contact, schedules, outputs)
stays the scene's. Where several settings meet, the most specific wins: keyword
overrides of Simulation (and the command line's --level, --full) over the preset given
to Simulation, that preset over the scene file, and in a scene file its own keys over
its [scene] fidelity.

The presets are picked from the Pareto front (largest error over time in lip aperture and
protrusion against CPU time) of the default sweep of `python benchmarks/accuracy_vs_time.py
--cost cpu` (a 0.1 s lip gesture with contact, against the fine half face at DEFAULT
tolerances; docs/accuracy.md):

    preset    mesh, DOF                   error aperture / protrusion   real-time factor (CPU)
    fast      medium half, 6300           0.21 / 0.06 mm                36
    balanced  medium half 2 rows, 11025   0.16 / 0.15 mm                76
    accurate  fine half (2 rows), 50925   the reference                 2317

Through-thickness rows buy more than in-plane levels (one row per layer stalls
near 0.18 mm); tolerances cost little accuracy against the mesh error; the half face
gives the full face's lip outputs; mean dilatation is needed ("full" locks). The coarse
level is cheap and 1.2 mm off (the reduced-order `realtime` fidelity is built on it).

What each preset sets is in PRESETS below: mesh level, rows, half face, formulation, and
tolerances with the lip/lip contact's penalty (`lip_penalty`, N/mm^3): `accurate`
DEFAULTS; `balanced` STEP_LOOSE (DEFAULTS but a substep error tolerance of 5e-2 mm,
Newton 1e-4 on the residual and 1e-2 mm on its last update); `fast` FAST (STEP_LOOSE's
tolerances but LOOSE's 10 ms substeps). A Newton residual tolerance of 1e-3 took case a of
benchmarks/fast_path.py to a cutback. `balanced` and `fast` soften the lip penalty to
LIP_SOFT (0.3), `accurate` keeps PENALTY (1, the default of a scene): at 1 the lip/lip
contact is two thirds of the reference face's time on benchmarks/fast_path.py
(docs/dev-notes/fast_path.md); at 0.3, OOP + BUC at 1 on the default scene puts a lip
node 0.056 mm behind the other lip's bilinear face, over the 0.05 mm of
solver/stability.py (0.049 mm at 0.5, 0.041 mm at 1; tests/test_stability.py). On an ANSYS face a preset sets the tolerances and half face
only (rows and level are the generic face's).
"""

from .errors import ParameterError
from .terms.contact import PENALTY

LOOSE = dict(substep_tol=1e-2, max_substep=1e-2, newton_rtol=1e-4, newton_utol=1e-4)
DEFAULTS = dict(substep_tol=1e-3, max_substep=5e-3, newton_rtol=1e-6, newton_utol=1e-5,
                lip_penalty=PENALTY)
# The lip/lip contact's penalty of `balanced` and `fast` (N/mm^3; PENALTY = 1 elsewhere):
# the module docstring
LIP_SOFT = 0.3
# DEFAULTS but the substep error tolerance 5e-2 mm, and Newton 1e-4 on the residual and
# 1e-2 mm on its last update: the module docstring
STEP_LOOSE = dict(DEFAULTS, substep_tol=5e-2, newton_rtol=1e-4, newton_utol=1e-2,
                  lip_penalty=LIP_SOFT)
# LOOSE but the substep error tolerance and Newton's last update, as STEP_LOOSE's (so that
# no preset is looser than a faster one)
FAST = dict(LOOSE, substep_tol=5e-2, newton_utol=1e-2, lip_penalty=LIP_SOFT)

PRESETS = {
    "fast": dict(level="medium", rows=1, half=True, formulation="mean_dilatation", **FAST),
    "balanced": dict(level="medium", rows=2, half=True, formulation="mean_dilatation",
                     **STEP_LOOSE),
    "accurate": dict(level="fine", rows=2, half=True, formulation="mean_dilatation",
                     **DEFAULTS),
}
FIDELITIES = tuple(PRESETS)

# --- reduced-order fidelities (solver.rom; issue 10) -----------------------------------
# Not presets of the full-order solver (not in FIDELITIES nor PRESETS): open_simulation(...,
# fidelity="realtime") (solver.entry), a scene file's `fidelity = "realtime"`, `facefmu run
# --fidelity realtime` and the FMU's fidelity parameter open a solver.rom.simulation.
# ReducedSimulation, whose full-order model (training snapshots, fallback) has these knobs.
REDUCED = {"realtime": dict(level="coarse", half=True, formulation="mean_dilatation",
                            **LOOSE)}


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
    """A new Scene: `scene` (solver.scene.Scene) with the preset `name`'s fields (its
    `fidelity` field, which makes open_simulation open the reduced model for "realtime",
    is left as it was: the full-order model at the realtime knobs is this scene)."""
    return scene.with_overrides(**fidelity_overrides(name, scene.anatomy))
