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

The presets are picked from the Pareto front (largest error over time in lip aperture and
protrusion against CPU time) of the default sweep of `python benchmarks/accuracy_vs_time.py
--cost cpu` (a 0.1 s lip gesture with contact, against the fine half face at DEFAULT
tolerances; docs/accuracy.md):

    preset    mesh, DOF                   error aperture / protrusion   real-time factor (CPU)
    fast      medium half, 6300           0.18 / 0.06 mm                203
    balanced  medium half 2 rows, 11025   0.15 / 0.12 mm                455
    accurate  fine half (2 rows), 50925   the reference                 5123

`balanced` takes the DEFAULT tolerances but a substep error tolerance of 1e-2 mm
(STEP_LOOSE). Run back to back on one worker (docs/accuracy.md), that halved its CPU
time (45.5 s against 93.2 s for the 0.1 s gesture) for 0.148 against 0.141 mm: the mesh
error hides the time-stepping error. Medium 2 rows at LOOSE (also 10 ms substeps and
Newton 1e-4) costs as much (43.5 s) for the same error, but at LOOSE the reference full
face failed benchmarks/fast_path.py's contact gesture at t = 0.18 s (Newton stalled after
every cutback), which it runs through at STEP_LOOSE. (balanced's real-time factor is from
that one-worker run, the others from the whole sweep, hours apart on a machine whose speed
drifts.) Since session 12 Newton's displacement criterion (its last update) is 1e-4 mm
in `balanced` and `fast` (1e-5 mm before; a hundredth of balanced's substep error
tolerance): on benchmarks/fast_path.py's gesture that took 377 Newton iterations against
453 on case b and 707 against 762 on case a, whose lip outputs moved by 2e-6 and 2e-5 mm
(docs/fast_path.md); the figures of the table above are from before. At 1e-3 mm with the
residual at 1e-4 (LOOSE's), case a stalled at t = 0.18 s, as at LOOSE.
Through-thickness rows buy more than in-plane levels (one row per layer stalls
near 0.18 mm); tolerances cost little accuracy against the mesh error; the half face
gives the full face's lip outputs; mean dilatation is needed ("full" locks). The coarse
level is cheap and 1.2 mm off (the reduced-order `realtime` fidelity is built on it). On an
ANSYS face a preset sets the tolerances and half face only (rows and level are the
generic face's).
"""

from .errors import ParameterError

LOOSE = dict(substep_tol=1e-2, max_substep=1e-2, newton_rtol=1e-4, newton_utol=1e-4)
DEFAULTS = dict(substep_tol=1e-3, max_substep=5e-3, newton_rtol=1e-6, newton_utol=1e-5)
# DEFAULTS but the substep error tolerance, and Newton's last update 1e-4 mm (session 12)
STEP_LOOSE = dict(DEFAULTS, substep_tol=1e-2, newton_utol=1e-4)

PRESETS = {
    "fast": dict(level="medium", rows=1, half=True, formulation="mean_dilatation", **LOOSE),
    "balanced": dict(level="medium", rows=2, half=True, formulation="mean_dilatation",
                     **STEP_LOOSE),
    "accurate": dict(level="fine", rows=2, half=True, formulation="mean_dilatation",
                     **DEFAULTS),
}
FIDELITIES = tuple(PRESETS)

# --- reduced-order fidelities (solver.rom; issue 10) -----------------------------------
# Not presets of the full-order solver (not in FIDELITIES nor PRESETS): Simulation(...,
# fidelity="realtime"), a scene file's `fidelity = "realtime"`, `facefmu run --fidelity
# realtime` and the FMU's fidelity parameter build a solver.rom.simulation.
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
    `fidelity` field, which makes Simulation build the reduced model for "realtime", is
    left as it was: the full-order model at the realtime knobs is this scene)."""
    return scene.with_overrides(**fidelity_overrides(name, scene.anatomy))
