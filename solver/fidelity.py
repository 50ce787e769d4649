"""Named fidelity presets: what a run trades between accuracy and time.

    Simulation("rounding_u", fidelity="balanced")       # the API
    facefmu run rounding_u --fidelity fast              # the command line
    [scene] fidelity = "fast"                           # a scene file
    fidelity = "accurate"                               # the FMU's String parameter

and, in all four places, "realtime": the reduced-order model of solver.rom (REDUCED
below; docs/realtime.md).

A preset replaces the numerical fields of a scene: the mesh level (of the generic face; an
ANSYS face keeps its own mesh), half face, substep error tolerance and largest substep,
Newton tolerance, element formulation and the lip/lip contact's penalty. The model
itself (anatomy, muscles, effects such as stiffening and contact, schedules, outputs)
stays the scene's. Where several settings
meet, the most specific wins: keyword overrides of Simulation (and the command line's
--level, --full) over the preset given to Simulation, that preset over the scene file,
and in a scene file its own keys over its [scene] fidelity.

The presets are picked from the Pareto front (largest error over time in lip aperture and
protrusion against CPU time) of the default sweep of `python benchmarks/accuracy_vs_time.py
--cost cpu` (a 0.1 s lip gesture with contact, against the fine half face at DEFAULT
tolerances; docs/accuracy.md):

    preset    mesh, DOF                   error aperture / protrusion   real-time factor (CPU)
    fast      medium half, 6300           0.21 / 0.06 mm                36
    balanced  medium half 2 rows, 11025   0.16 / 0.15 mm                76
    accurate  fine half (2 rows), 50925   the reference                 2317

(session 18's preset runs against session 16's fine reference, below; the older figures of
the whole sweep in docs/accuracy.md.)

Tolerances (substep error, largest substep, Newton's residual and last update):
`accurate` DEFAULTS; `balanced` STEP_LOOSE, DEFAULTS but 5e-2 mm, Newton 1e-4 and 1e-2
mm; `fast` FAST, LOOSE's 10 ms substeps and Newton 1e-4 with 5e-2 mm and 1e-2 mm. The
substep tolerances since session 16 (before: balanced 1e-2 mm from session 7, fast LOOSE),
Newton's since session 17 (balanced 1e-5 / 1e-3 mm in session 16, 1e-6 / 1e-4 mm from
session 12; fast 1e-4 / 1e-3 mm, LOOSE's 1e-4 / 1e-4 mm before). Newton's, measured in
session 17: the sweep's `--only "preset balanced,preset fast" --merge` gave the same
errors to 1e-4 mm (balanced 0.156 / 0.152 mm in 7.8 s of CPU against 8.3 s; fast 0.208 /
0.063 mm, 3.6 against 3.4 s, within the noise); on benchmarks/fast_path.py, one run after
the other, case a took 233 Newton iterations against 291 and 35.7 / 37.2 s against 38.6 /
39.2 s, case b 181 against 227 and 12.2 / 13.4 s against 14.9 / 13.6 s (a later
alternation in a slower hour: both cases within the machine's drift), the lip outputs
within 1e-4 mm of session 16's tolerances (docs/dev-notes/fast_path.md). A residual tolerance of
1e-3 took case a to a cutback.
Lip penalty (`lip_penalty`, N/mm^3): `balanced` and `fast` 0.3 (LIP_SOFT) since session 18,
`accurate` 1 (PENALTY, the default of a scene). The lip/lip contact was two thirds of the
reference face's time on benchmarks/fast_path.py; at 0.3 case a took 162 Newton iterations
against 233 and 17.5 s against 26.5 s one call after the other, its deepest penetration
0.030 mm (under the 0.05 mm of solver/stability.py), the lip outputs within 3.4e-3 mm; the
sweep's preset runs gave the same errors against fine to 1e-3 mm (balanced 7.6 s of CPU,
fast 3.6 s; docs/dev-notes/fast_path.md, docs/accuracy.md). At 0.2 the penetration was
0.042 mm, at 0.1 0.076 mm.
The sweep's tolerance runs, each preset at tighter substep tolerances and otherwise as it
is, in one call (`python benchmarks/accuracy_vs_time.py --cost cpu --only
"preset balanced,preset fast,balanced at substep_tol 0.01,..." --merge DIR`, two runs at a
time; session 16, at its Newton tolerances; CPU s for the 0.1 s gesture, aperture /
protrusion error against fine, mm):

    balanced at 1e-2            14.4 s   0.148 / 0.121
    balanced at 2e-2            12.7 s   0.151 / 0.131
    balanced at 3e-2            10.6 s   0.154 / 0.146
    balanced (5e-2)              8.5 s   0.156 / 0.152
    fast at 1e-2                 7.4 s   0.185 / 0.051
    fast (5e-2)                  3.5 s   0.208 / 0.063

(Newton's new tolerances alone, at 1e-2 mm, moved the outputs by 1e-6 mm in a scratch run.)
The larger error of the two rises by 5 % (balanced) and 12 % (fast) for 41 % and 53 %
less time: the mesh error still dominates. On the contact gesture of
benchmarks/fast_path.py balanced took case a from 406 to 281 Newton iterations and case b
from 362 to 206, lip outputs within 0.015 mm of the old preset's
(docs/dev-notes/fast_path.md), case a without a cutback. (In session 7 LOOSE, and in session 12
Newton at 1e-3 mm, stalled case a at t = 0.18 s; the contact law has been mended since, in
sessions 14 and 15.)
Through-thickness rows buy more than in-plane levels (one row per layer stalls
near 0.18 mm); tolerances cost little accuracy against the mesh error; the half face
gives the full face's lip outputs; mean dilatation is needed ("full" locks). The coarse
level is cheap and 1.2 mm off (the reduced-order `realtime` fidelity is built on it). On an
ANSYS face a preset sets the tolerances and half face only (rows and level are the
generic face's).
"""

from .errors import ParameterError
from .terms.contact import PENALTY

LOOSE = dict(substep_tol=1e-2, max_substep=1e-2, newton_rtol=1e-4, newton_utol=1e-4)
DEFAULTS = dict(substep_tol=1e-3, max_substep=5e-3, newton_rtol=1e-6, newton_utol=1e-5,
                lip_penalty=PENALTY)
# The lip/lip contact's penalty of `balanced` and `fast` (N/mm^3; PENALTY = 1 elsewhere):
# session 18, the module docstring
LIP_SOFT = 0.3
# DEFAULTS but the substep error tolerance 5e-2 mm (1e-2 from session 7, 1e-3 before:
# session 16), and Newton 1e-4 on the residual and 1e-2 mm on its last update (session 17;
# 1e-5 / 1e-3 mm in session 16, 1e-6 / 1e-4 mm from session 12): the module docstring
STEP_LOOSE = dict(DEFAULTS, substep_tol=5e-2, newton_rtol=1e-4, newton_utol=1e-2,
                  lip_penalty=LIP_SOFT)
# LOOSE but the substep error tolerance and Newton's last update, as STEP_LOOSE's (so that
# no preset is looser than a faster one): sessions 16 and 17
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
