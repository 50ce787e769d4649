"""The hard cases through the FMU: the case as the FMU runner's input, and its checks.

The stress run and the quick tests run a case through the built FMU with fmpy
(tests/fmu_scripts/stress_case.py) as well as in this process (runner.run_case):
``fmu_spec`` describes the case for that script (the scene written as a scene file, the
FMU's parameters from it, the steps), and ``check_fmu_run`` checks what it returned: the
same steps, the same refusals (fmi2Discard with the outputs unchanged), finite outputs
within bounds, statistics reported, memory bounded, exact rollback repeats, and the same
outputs as the run in this process within FMU_MATCH_TOLERANCE. Checking the FMU against
the process, rather than on its own, is what shows that the FMU wraps the same model.
"""

import numpy as np

from solver.app.scene import parse_scene
from solver.face.face_model import LIP_OUTPUTS
from solver.validation.stability.catalogue import to_toml
from solver.validation.stability.runner import MEMORY_LIMIT_MB, max_change

# mm: FMU outputs against the same case run in this process. The FMU solves with SuperLU,
# the process with the scene's solver (PARDISO where it installs): Newton stops within its
# tolerances (newton_utol 1e-5 or 1e-4 mm), so the adaptive substeps may differ, each
# within substep_tol.
FMU_MATCH_TOLERANCE = 1e-3


def fmu_spec(case, scene_path):
    """The JSON description of a case for tests/fmu_scripts/stress_case.py (the scene
    written to scene_path; the FMU's fidelity, anatomy, level, half_face, tolerance and
    max_substep parameters from it)."""
    from pathlib import Path
    Path(scene_path).write_text(to_toml(case.scene))
    sc = parse_scene(case.scene)
    return {"name": case.name, "scene": str(scene_path), "fidelity": sc.fidelity,
            "anatomy": sc.anatomy, "level": sc.level, "half": sc.half,
            "tolerance": sc.substep_tol,
            "max_substep": sc.max_substep, "steps": [[h, a] for h, a in case.steps],
            "memory": case.memory, "rollback": case.rollback}


def check_fmu_run(case, result, reference=None, bounds=None):
    """Problems (list) of a case's FMU run (stress_case.py's result for it): the refused
    steps (fmi2Discard with the outputs unchanged) are the case's, outputs finite and in
    bounds, statistics reported, memory bounded, and the outputs equal to the same case
    run in this process (reference: its CaseRun) within FMU_MATCH_TOLERANCE."""
    if "init_status" in result:
        return ([f"initialization failed with status {result['init_status']}"],
                {"memory_growth_mb": float("nan"), "fmu_vs_solver": float("nan")})
    problems = []
    refused = [k for k, s in enumerate(result["statuses"]) if s != 0]
    if refused != list(case.refused):
        problems.append(f"refused steps {refused}, expected {list(case.refused)} "
                        f"(statuses {sorted(set(result['statuses']))})")
    for k, (s, row) in enumerate(zip(result["statuses"], result["rows"])):
        if s == 0:
            bad = [key for key in LIP_OUTPUTS if not np.isfinite(row[key])]
            if bad:
                problems.append(f"step {k}: non-finite {bad}")
                continue
            for key, (lo, hi) in (bounds or {}).items():
                if not lo <= row[key] <= hi:
                    problems.append(f"step {k}: {key} = {row[key]:.6g} outside [{lo:.3g}, {hi:.3g}]")
            if not (row["substeps"] >= 1 and row["newton_iterations"] >= 0):
                problems.append(f"step {k}: statistics {row['substeps']}, "
                                f"{row['newton_iterations']}")
        elif s != 2:
            problems.append(f"step {k}: status {s} (fmi2Discard expected)")
        elif not row["unchanged"]:
            problems.append(f"step {k}: refused step changed the outputs")
        if len(problems) > 20:
            break
    if case.rollback:
        rb = result.get("rollback") or {}
        if rb.get("repeats") != case.rollback or not rb.get("identical"):
            problems.append(f"rollback: {rb.get('repeats')} of {case.rollback} repeats, "
                            f"identical {rb.get('identical')} ({rb.get('problem', '')})")
    mem = result.get("memory", {})
    growth = mem["end"] - mem["start"] if "start" in mem and "end" in mem else float("nan")
    if growth > MEMORY_LIMIT_MB:
        problems.append(f"memory grew by {growth:.1f} MB")
    change = float("nan")
    if reference is not None:
        ok = [r for r in result["rows"] if "refused" not in r]
        change = max_change(ok, reference.rows)
        if not change <= FMU_MATCH_TOLERANCE:
            problems.append(f"FMU outputs differ from the solver's by {change:.3g} mm")
    return problems, {"memory_growth_mb": growth, "fmu_vs_solver": change}
