"""Running a case in this process, and the invariants every case must keep.

``run_case`` runs a Case (catalogue) through the scene's simulation (solver.entry) and
checks the invariants the package docstring lists after every accepted step (every tenth
in runs of more than 1000 steps): ``check_state`` for the state (finite, det F > 0, the
penetrations the probe measures outside the model, at most CONTACT_TOLERANCE where the
scene's contact is on, output_bounds), and here the dissipation, the statistics, the
refusals (the state unchanged, and a replay without the refused steps equal bit for bit),
memory growth, settling on the static equilibrium (static_equilibrium), exact rollback
repeats. It returns a CaseRun: the outputs after each step, the worst values, problems.
These checks live apart from the model's own so that a run is judged by what it did,
not by what the model reports of itself.

Convergence: ``Case.halved()`` halves every substep (catalogue.halved: substep_tol / 4
and max_substep halved), over the case or its first halving_time seconds; the lip outputs
at the communication points must then change (``halving_change``) by less than
``halving_limit(run)``: HALVING_TOLERANCE, times sqrt(tol / HALVING_AT) for a substep
tolerance tol looser than HALVING_AT, plus HALVING_RELATIVE of the largest lip-output
excursion from the start of the case. A reduced run (fixed substeps) is held to
HALVING_TOLERANCE.

The invariants in full and the argument for the halving test's limits: docs/method.md,
section 'Stability cases: invariants and the halving test'.
"""

import math
import os
import resource
import time
from dataclasses import dataclass, field

import numpy as np

from solver.app.fidelity import REDUCED
from solver.app.scene import parse_scene
from solver.face.face_model import LIP_OUTPUTS
from solver.face.terms.contact import TOLERANCE
from solver.validation.stability.probe import Probe

CONTACT_TOLERANCE = TOLERANCE  # mm: penalty contact's allowed penetration
HALVING_TOLERANCE = 0.05    # mm: largest change of a lip output when every substep is halved,
HALVING_RELATIVE = 0.02     # plus this fraction of the largest excursion of the lip outputs
HALVING_AT = 1e-3           # mm: the substep tolerance HALVING_TOLERANCE is for (the default)
MEMORY_LIMIT_MB = 50.0      # resident memory growth allowed over a long run
REST_TOLERANCE = 1e-9       # mm: at rest nothing moves
EQUILIBRIUM_TOLERANCE = 0.01    # mm: a held activation ends this close to the static state


# ------------------------------------------------------------------------ invariants

def min_det_f(mesh, u):
    """The smallest det F over all Gauss points of all bricks for displacements u (n, 3)."""
    grad = np.einsum("mai,mgaj->mgij", np.asarray(u, dtype=float)[mesh.bricks], mesh.dn_dx)
    return float(np.linalg.det(grad + np.eye(3)).min())


def output_bounds(anatomy):
    """name -> (lo, hi) sanity bounds of the lip outputs (mm) from the face's size."""
    ext = np.ptp(anatomy.mesh.nodes, axis=0)
    width = 2 * ext[0] if anatomy.half else ext[0]
    b = {"lip_aperture": (0.0, ext[2]), "lip_width": (1e-9, width)}
    for k in ("lip_protrusion", "upper_lip_protrusion", "lower_lip_protrusion"):
        b[k] = (-ext[1], ext[1])
    return b


def check_state(sim, probe=None, bounds=None):
    """Invariants of a simulation's current state: (measures dict, problems list)."""
    u = sim.u                                   # a reduced model's, reconstructed
    v = sim.v
    problems = []
    finite = bool(np.all(np.isfinite(u)) and np.all(np.isfinite(v)))
    out = sim.outputs()
    if not finite:
        problems.append("non-finite displacement or velocity")
    bad = [k for k, x in out.items() if not np.isfinite(x)]
    if bad:
        problems.append(f"non-finite outputs {bad}")
    jmin = min_det_f(sim.anatomy.mesh, u) if finite else float("nan")
    if not jmin > 0:
        problems.append(f"inverted brick: min det F = {jmin:.3g}")
    lips = teeth = 0.0
    if probe is not None and finite:
        lips, teeth = probe.penetrations(u)
        if sim.scene.lip_contact and lips > CONTACT_TOLERANCE:
            where = ", ".join(f"node {n} in brick {b} ({d:.3g} mm)" for n, b, d in probe.inside
                              if d > CONTACT_TOLERANCE)
            problems.append(f"lip penetration {lips:.3g} mm > {CONTACT_TOLERANCE} mm: {where}")
        if sim.scene.teeth_contact and teeth > CONTACT_TOLERANCE:
            problems.append(f"lip/teeth penetration {teeth:.3g} mm > {CONTACT_TOLERANCE} mm")
    for k, (lo, hi) in (bounds or output_bounds(sim.anatomy)).items():
        if k in out and not lo <= out[k] <= hi:
            problems.append(f"{k} = {out[k]:.6g} mm outside [{lo:.3g}, {hi:.3g}]")
    return {"min_det_f": jmin, "lip_penetration": lips, "teeth_penetration": teeth,
            "finite": finite}, problems


def rss_mb():
    """The process's current resident memory (MB; Linux), else its peak."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


# ------------------------------------------------------------------------------- runs

@dataclass
class CaseRun:
    """What a case did: outputs after each step (rows), the worst values, problems."""

    name: str
    rows: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    steps: int = 0
    refused: list = field(default_factory=list)      # indices of refused steps
    substeps: int = 0
    newton_iterations: int = 0
    cutbacks: int = 0
    worst_cutbacks: int = 0                          # most cutbacks in one step
    min_det_f: float = np.inf
    lip_penetration: float = 0.0
    teeth_penetration: float = 0.0
    dissipated: float = 0.0
    memory_growth_mb: float = float("nan")
    equilibrium_change: float = float("nan")
    equilibrium_distances: list = field(default_factory=list)
    rollbacks: int = 0                               # repeats of the rolled-back step
    start: dict = field(default_factory=dict)        # lip outputs before the first step
    substep_tol: float = None                        # mm: the adaptive stepper's (None: fixed)
    fallbacks: int = 0                               # a reduced run's handovers to the full model
    wall: float = 0.0

    @property
    def passed(self):
        return not self.problems

    def problem(self, step, text):
        if len(self.problems) < 20:
            self.problems.append(f"step {step}: {text}" if step is not None else text)


def _snapshot(sim):
    st = sim.get_state(fresh=False)             # a look that leaves the run as it was
    return st, sim.integrator.dissipated if sim.integrator is not None else 0.0


def _unchanged(sim, snap):
    (st, dissipated) = snap
    now, d = _snapshot(sim)
    return (now["t"] == st["t"] and d == dissipated
            and all(np.array_equal(now[k], st[k]) for k in ("u", "v", "q", "v_r", "activation", "pattern")
                    if k in st))


def lip_outputs(sim):
    out = sim.outputs()
    return {k: float(out[k]) for k in LIP_OUTPUTS}


def _set_inputs(sim, acts):
    """A step's inputs: activations (muscle -> a, 0 where absent) and, where the model
    has a jaw, its pose ('jaw_opening' deg, 'jaw_protrusion' mm, 0 where absent)."""
    sim.set_activations({m: acts.get(m, 0.0) for m in sim.face.muscles})
    if sim.face.jaw is not None:
        sim.set_jaw(acts.get("jaw_opening", 0.0), acts.get("jaw_protrusion", 0.0))


def run_case(case, progress=None, probe=True):
    """Run a Case in this process; returns a CaseRun. progress(k, n) is called after
    each step; probe: measure penetrations."""
    from solver.entry import open_simulation
    t_start = time.perf_counter()
    run = CaseRun(case.name)
    scene = parse_scene(case.scene, f"<case {case.name}>")
    sim = open_simulation(scene)
    if scene.fidelity not in REDUCED:
        run.substep_tol = float(scene.substep_tol)
    pr = Probe(sim.anatomy, jaw=sim.face.jaw) if probe else None
    bounds = output_bounds(sim.anatomy)
    n = len(case.steps)
    every = 1 if n <= 1000 else 10            # long runs: invariants at every 10th step
    mem0 = None
    target = static_equilibrium(case, sim) if case.equilibrium else None
    distances = []
    run.start = lip_outputs(sim)
    for k, (h, acts) in enumerate(case.steps):
        if case.memory and k == max(1, n // 10):
            mem0 = rss_mb()
        snap = _snapshot(sim)
        _set_inputs(sim, acts)
        stats = sim.step(sim.t + h)
        run.cutbacks += stats.cutbacks
        run.worst_cutbacks = max(run.worst_cutbacks, stats.cutbacks)
        if not stats.converged:
            run.refused.append(k)
            if not _unchanged(sim, snap):
                run.problem(k, "refused step changed the state")
            if k not in case.refused:
                run.problem(k, f"refused at t = {sim.t:.6g} s: {stats.reason}")
                break
            continue
        if k in case.refused:
            run.problem(k, "the step should have been refused")
        run.steps += 1
        run.substeps += stats.substeps
        run.newton_iterations += stats.newton_iterations
        out = sim.outputs()
        if not (stats.substeps >= 1 and stats.newton_iterations >= 0 and stats.cutbacks >= 0
                and out["cutbacks"] == stats.cutbacks):
            run.problem(k, f"statistics {stats.substeps=}, {stats.newton_iterations=}, "
                           f"{stats.cutbacks=}, outputs cutbacks {out['cutbacks']}")
        d = sim.integrator.dissipated
        if not d >= snap[1]:
            run.problem(k, f"dissipated energy fell from {snap[1]:.6g} to {d:.6g} mJ")
        if k % every == 0 or k == n - 1:
            m, problems = check_state(sim, pr, bounds)
            for p in problems:
                run.problem(k, p)
            run.min_det_f = min(run.min_det_f, m["min_det_f"])
            run.lip_penetration = max(run.lip_penetration, m["lip_penetration"])
            run.teeth_penetration = max(run.teeth_penetration, m["teeth_penetration"])
        if target is not None and (k + 1) % max(1, n // 10) == 0:
            now = lip_outputs(sim)
            distances.append(max(abs(now[key] - target[key]) for key in LIP_OUTPUTS))
            if len(distances) > 1 and distances[-1] > distances[-2] + 1e-6:
                run.problem(k, f"drifting: {distances[-1]:.4g} mm from the static "
                               f"equilibrium, was {distances[-2]:.4g} mm")
        run.dissipated = d
        run.rows.append({"t": sim.t, **lip_outputs(sim), "cutbacks": stats.cutbacks,
                         "substeps": stats.substeps,
                         "newton_iterations": stats.newton_iterations})
        if progress:
            progress(k + 1, n)
    run.fallbacks = int(getattr(sim, "fallbacks", 0))
    if case.rollback and run.steps == n:
        h, acts = case.steps[-1]
        saved, t_saved, first = sim.get_state(), sim.t, None
        for i in range(case.rollback):
            sim.set_state(saved)
            _set_inputs(sim, acts)
            if not sim.step(t_saved + h).converged:
                run.problem(n, f"repeat {i} of the rolled-back step refused")
                break
            out = lip_outputs(sim)
            first = first or out
            if out != first:
                run.problem(n, f"repeat {i} of the rolled-back step differs: {out} "
                               f"against {first}")
                break
        run.rollbacks = i + 1
        sim.set_state(saved)
    missing = [k for k in case.refused if k not in run.refused]
    if missing:
        run.problem(None, f"steps {missing} should have been refused")
    elif case.refused and run.steps == n - len(case.refused):
        _check_replay(case, run)
    if case.rest:
        moved = float(np.abs(sim.u).max())
        if not moved < REST_TOLERANCE:
            run.problem(None, f"at rest the face moved by {moved:.3g} mm")
    if case.memory and mem0 is not None:
        run.memory_growth_mb = rss_mb() - mem0
        if run.memory_growth_mb > MEMORY_LIMIT_MB:
            run.problem(None, f"memory grew by {run.memory_growth_mb:.1f} MB")
    if case.equilibrium:
        if target is None:
            run.problem(None, "no static equilibrium to compare with")
        run.equilibrium_distances = distances
        run.equilibrium_change = distances[-1] if distances else float("nan")
        if not run.equilibrium_change <= EQUILIBRIUM_TOLERANCE:
            run.problem(None, f"ends {run.equilibrium_change:.4g} mm from the static "
                              f"equilibrium (tolerance {EQUILIBRIUM_TOLERANCE} mm)")
    run.wall = time.perf_counter() - t_start
    sim.release()
    return run


def _check_replay(case, run):
    """A refusal leaves no trace: a fresh simulation that never saw the refused steps
    gives the same lip outputs after every accepted step, bit for bit."""
    from solver.entry import open_simulation
    sim = open_simulation(parse_scene(case.scene, f"<case {case.name}, replayed>"))
    kept = [s for k, s in enumerate(case.steps) if k not in case.refused]
    for i, (h, acts) in enumerate(kept):
        _set_inputs(sim, acts)
        if not sim.step(sim.t + h).converged:
            run.problem(None, f"the replay without the refused steps refused step {i}")
            break
        now, then = lip_outputs(sim), run.rows[i]
        if any(now[key] != then[key] for key in LIP_OUTPUTS):
            run.problem(None, f"accepted step {i} differs from a replay without the "
                              f"refused steps: {now} against {then}")
            break
    sim.release()


def static_equilibrium(case, sim):
    """Lip outputs of the static equilibrium at the case's last activations (None when
    the static solve fails)."""
    from solver.app.simulation import Simulation
    scene = {k: dict(v) for k, v in case.scene.items()}
    scene["scene"]["analysis"] = "static"
    static = Simulation(parse_scene(scene), loaded_anatomy=sim.anatomy)
    static.set_activations({m: case.steps[-1][1].get(m, 0.0) for m in static.face.muscles})
    if not static.step(1.0).converged:
        return None
    return lip_outputs(static)


def halving_change(run, half):
    """Largest change (mm) of a lip output between a case's run and its halved run
    (Case.halved(), possibly a prefix of the case): inf when the halved run failed."""
    if not half.passed or not half.rows:
        return float("inf")
    return max_change(run.rows[:len(half.rows)], half.rows)


def halving_limit(run):
    """The largest lip-output change (mm) allowed when the substeps of run are halved:
    HALVING_TOLERANCE sqrt(max(1, tol / HALVING_AT)), tol the run's substep tolerance (1
    for a reduced run), plus HALVING_RELATIVE of the largest excursion (module docstring)."""
    excursion = max((abs(r[k] - run.start[k]) for r in run.rows for k in LIP_OUTPUTS),
                    default=0.0)
    scale = math.sqrt(max(1.0, run.substep_tol / HALVING_AT)) if run.substep_tol else 1.0
    return HALVING_TOLERANCE * scale + HALVING_RELATIVE * excursion


def max_change(rows_a, rows_b, keys=LIP_OUTPUTS):
    """Largest |difference| of the outputs keys over rows at the same communication points
    (inf when the runs did not take the same steps)."""
    if len(rows_a) != len(rows_b) or not rows_a:
        return float("inf")
    return max(abs(a[k] - b[k]) for a, b in zip(rows_a, rows_b) for k in keys)
