"""Hard cases and the invariants they must keep, shared by the quick tests
(tests/test_stability.py) and the stress run (benchmarks/stress.py -> docs/stability.md).

A case (Case) is a scene, written as TOML sections in a dict, and a list of communication
steps (step size s, activations): a master's loop. ``cases(full)`` lists them, read from
the catalogue cases.toml: the quick versions (CI) or the full ones (the stress run).
``run_case`` runs a case in this process and checks, after every accepted step (every
tenth in runs of more than 1000 steps; ``check_state``):

  finite        u, v and every output are finite
  det F         det F > 0 at every Gauss point of every brick (no brick is inverted)
  penetration   the deepest lip-into-tissue and tissue-into-teeth penetration (mm),
                measured outside the model (``Probe``), also where the scene's contact
                is off; at most CONTACT_TOLERANCE where it is on
  bounds        lip_aperture >= 0, lip_width > 0, every lip output within the face's size
  dissipation   the damping's dissipated energy never decreases
  statistics    substeps >= 1, Newton iterations >= 0 and cutbacks >= 0

A refused step must leave the state exactly as it was, and the accepted steps must equal,
bit for bit, a fresh run that never tried the refused ones. Long runs also check memory
and settling; rollback cases, exact repeats. Through the FMU (``fmu_spec``,
``check_fmu_run``): the same steps, the same refusals (fmi2Discard), the same outputs
within FMU_MATCH_TOLERANCE. Convergence: halving every substep (``Case.halved()``) must
change the lip outputs by less than ``halving_limit(run)``.

One module per concern: catalogue (Case, the scene builder, the schedules, ``cases``,
``configured``, ``halved``, ``to_toml``), probe (Probe and its own geometry), runner
(``run_case``, CaseRun, ``check_state``, the halving check), fmu (``fmu_spec``,
``check_fmu_run``). Every public name of the four is exported here, so that
`from solver.validation import stability as S` and `S.run_case` work as before the split.
The invariants in full and the argument for the halving test's limits: docs/method.md,
section 'Stability cases: invariants and the halving test'.
"""

from solver.face.face_model import LIP_OUTPUTS  # noqa: F401 (S.LIP_OUTPUTS, as before)
from solver.validation.stability.catalogue import (Case, cases, configured, halved,
                                                   random_steps, scene_dict,
                                                   switching_steps, to_toml)
from solver.validation.stability.fmu import FMU_MATCH_TOLERANCE, check_fmu_run, fmu_spec
from solver.validation.stability.probe import (FACE_DIVISIONS, HEX_FACES, PROBE_DEPTH, Probe,
                                               brick_winding, face_sampling, inside_bricks,
                                               point_triangle_distance)
from solver.validation.stability.runner import (CONTACT_TOLERANCE, EQUILIBRIUM_TOLERANCE,
                                                HALVING_AT, HALVING_RELATIVE,
                                                HALVING_TOLERANCE, MEMORY_LIMIT_MB,
                                                REST_TOLERANCE, CaseRun, check_state,
                                                halving_change, halving_limit, lip_outputs,
                                                max_change, min_det_f, output_bounds,
                                                rss_mb, run_case, static_equilibrium)

__all__ = [
    # catalogue
    "Case", "cases", "configured", "halved", "random_steps", "scene_dict",
    "switching_steps", "to_toml",
    # probe
    "FACE_DIVISIONS", "HEX_FACES", "PROBE_DEPTH", "Probe", "brick_winding",
    "face_sampling", "inside_bricks", "point_triangle_distance",
    # runner
    "CONTACT_TOLERANCE", "EQUILIBRIUM_TOLERANCE", "HALVING_AT", "HALVING_RELATIVE",
    "HALVING_TOLERANCE", "MEMORY_LIMIT_MB", "REST_TOLERANCE", "CaseRun", "check_state",
    "halving_change", "halving_limit", "lip_outputs", "max_change", "min_det_f",
    "output_bounds", "rss_mb", "run_case", "static_equilibrium",
    # fmu
    "FMU_MATCH_TOLERANCE", "check_fmu_run", "fmu_spec",
]
