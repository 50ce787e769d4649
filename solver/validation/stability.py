"""Hard cases and the invariants they must keep, shared by the quick tests
(tests/test_stability.py) and the stress run (benchmarks/stress.py -> docs/stability.md).

A case is a scene, written as TOML sections in a dict (so that the same case runs here
through Simulation and through the FMU as a scene file), and a list of communication
steps (step size s, activations): a master's loop, which sets the activations and then
takes the step (with the scene's hold: "step" jumps at the start of the step, "ramp"
ramps over it). ``cases(full)`` lists them; the quick versions are short cuts of the full.

Invariants, checked by ``run_case`` after every accepted step (every tenth in runs of
more than 1000 steps; ``check_state``):

  finite        u, v and every output are finite
  det F         det F > 0 at every Gauss point of every brick (no brick is inverted)
  penetration   the deepest lip-into-tissue and tissue-into-teeth penetration (mm),
                measured outside the model (``Probe``), also where the scene's contact
                is off; at most CONTACT_TOLERANCE where it is on
  bounds        lip_aperture >= 0, lip_width > 0, every lip output within the face's size
  dissipation   the damping's dissipated energy never decreases
  statistics    substeps >= 1, Newton iterations >= 0 and cutbacks >= 0
A refused step must leave the state exactly as it was, and the accepted steps must equal,
bit for bit, a fresh run that never tried the refused ones; a case expects no refusal
unless it names the step. ``run_case`` returns the outputs after each step and the worst
values seen. Long runs also check memory and settling; rollback cases, exact repeats.
Through the FMU (``fmu_spec``, ``check_fmu_run``, tests/fmu_scripts/stress_case.py): the
same steps with fmpy, the same refusals (fmi2Discard), and the same outputs as in this
process within FMU_MATCH_TOLERANCE.

Convergence: ``Case.halved()`` halves every substep (``halved(scene)``: substep_tol / 4
and max_substep halved), over the case or its first halving_time seconds; the lip outputs
at the communication points must then change by less than ``halving_limit(run)``:
HALVING_TOLERANCE, times sqrt(tol / HALVING_AT) for a substep tolerance tol looser than
HALVING_AT, plus HALVING_RELATIVE of the largest lip-output excursion from the start of
the case. A reduced run (fixed substeps) is held to HALVING_TOLERANCE.

The invariants in full and the argument for the halving test's limits: docs/method.md,
section 'Stability cases: invariants and the halving test'.
"""

import math
import os
import resource
import time
from pathlib import Path
from dataclasses import dataclass, field, replace

import numpy as np

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.core.assembly import Assembly, Pattern
from solver.face.face_model import LIP_OUTPUTS
from solver.face.jaw import BONWILL_MM
from solver.app.scene import parse_scene
from solver.face.terms.contact import TOLERANCE
from solver.app.fidelity import REDUCED
from solver.rom.stepper import H_MAX
from solver.core.terms.base import State

CONTACT_TOLERANCE = TOLERANCE  # mm: penalty contact's allowed penetration
HALVING_TOLERANCE = 0.05    # mm: largest change of a lip output when every substep is halved,
HALVING_RELATIVE = 0.02     # plus this fraction of the largest excursion of the lip outputs
HALVING_AT = 1e-3           # mm: the substep tolerance HALVING_TOLERANCE is for (the default)
MEMORY_LIMIT_MB = 50.0      # resident memory growth allowed over a long run
REST_TOLERANCE = 1e-9       # mm: at rest nothing moves
EQUILIBRIUM_TOLERANCE = 0.01    # mm: a held activation ends this close to the static state
PROBE_DEPTH = 5.0           # mm: deepest lip-into-teeth penetration the probe sees
FACE_DIVISIONS = 16         # sub-quads per edge of a lip face, for the probe's depth


# ------------------------------------------------------------------------------ cases

@dataclass
class Case:
    """name; what it tests; scene: TOML sections (dict); steps: [(s, {muscle: a})];
    refused: indices of the steps that must be refused (state unchanged); halving: run
    the convergence check, over the first halving_time seconds (None: all the steps);
    rest: nothing may move; memory: measure memory growth; equilibrium: track the largest
    lip-output distance to the static equilibrium at the last activations, at ten
    checkpoints: it must never grow (no drift) and end within EQUILIBRIUM_TOLERANCE;
    rollback: after the steps, restore the state this many times and repeat the last step:
    every repeat must give the same outputs, bit for bit (an FMU master's rollback);
    not_applicable: why the case does not run on its configuration (None: it runs)."""

    name: str
    description: str
    scene: dict
    steps: list
    refused: tuple = ()
    halving: bool = True
    rest: bool = False
    memory: bool = False
    equilibrium: bool = False
    halving_time: float = None
    rollback: int = 0
    not_applicable: str = None

    @property
    def duration(self):
        return float(sum(s for s, _ in self.steps))

    def halved(self):
        """The case with every substep halved (see the module docstring), over its first
        halving_time seconds."""
        steps = self.steps
        if self.halving_time is not None:
            ends = np.cumsum([h for h, _ in steps])
            steps = steps[:int(np.searchsorted(ends, self.halving_time - 1e-12)) + 1]
        return replace(self, name=f"{self.name} (halved)", steps=steps,
                       scene=halved(self.scene, min(h for h, _ in self.steps)))


def scene_dict(name, driven, hold="step", lips=True, teeth=True, **solver):
    """TOML sections of a transient case on the coarse generic half face."""
    return {"scene": {"name": name, "analysis": "transient"},
            "anatomy": {"source": "generic", "level": "coarse", "half": True},
            "muscles": {"driven": list(driven)},
            "effects": {"lip_contact": lips, "teeth_contact": teeth},
            "solver": {"hold": hold, **solver}}


def configured(case, anatomy="generic", level=None, fidelity=None):
    """The case on another configuration: anatomy ("generic" or an ANSYS face folder),
    level (the generic face's; None: the case's, or the fidelity's where one is given) and
    fidelity (a preset of solver.app.fidelity, as a scene file's `fidelity`; None: the case's
    own tolerances). The name says which.

    "realtime" opens the shipped reduced model (solver.rom.store), whose key is the default
    scene's: the case then drives all ten muscles (those it does not name stay at 0), and a
    case that scales a muscle's force is outside every such model (not_applicable says so)."""
    scene = {k: dict(v) for k, v in case.scene.items()}
    skip = None
    if fidelity in REDUCED:
        scene["muscles"]["driven"] = list(MUSCLE_NAMES)
        if scene["muscles"].get("force_scale"):
            skip = (f"its force scales {scene['muscles']['force_scale']} are outside the "
                    "shipped reduced model, which has the default scene's constants")
    tags = []
    if str(anatomy) != "generic":
        scene["anatomy"] = {"source": str(anatomy), "half": True}
        tags.append("reference" if "reference" in str(anatomy) else Path(anatomy).name)
    elif level or fidelity:
        scene["anatomy"].pop("level")
        if level:
            scene["anatomy"]["level"] = level
            tags.append(level)
    if fidelity:
        scene["scene"]["fidelity"] = fidelity
        tags.append(fidelity)
    if not tags:
        return case
    return replace(case, name=f"{case.name}@{'+'.join(tags)}", scene=scene,
                   not_applicable=skip)


def _ramp(t, t_full, value):
    return value * min(1.0, t / t_full)


def random_steps(seed, segments, muscles=MUSCLE_NAMES, sizes=(0.002, 0.01, 0.03)):
    """Random activations in [0, 1] for muscles, each held over a step of a random size."""
    rng = np.random.default_rng(seed)
    return [(float(rng.choice(sizes)), {m: float(a) for m, a in
                                        zip(muscles, rng.uniform(0.0, 1.0, len(muscles)))})
            for _ in range(segments)]


def switching_steps(seed, n, muscles=MUSCLE_NAMES, shortest=0.001, longest=0.02):
    """n steps of a size drawn uniformly in [shortest, longest] s (rounded to 0.1 ms), each
    with new activations in [0, 1] for all muscles, from numpy's generator seeded seed."""
    rng = np.random.default_rng(seed)
    return [(round(float(rng.uniform(shortest, longest)), 4),
             {m: float(a) for m, a in zip(muscles, rng.uniform(0.0, 1.0, len(muscles)))})
            for _ in range(n)]


def cases(full=False):
    """The hard cases: quick versions (CI) or the full ones (the stress run)."""
    all_on = {m: 1.0 for m in MUSCLE_NAMES}
    out = []
    # all ten muscles stepped from 0 to 1 at once (and, in full, released at once)
    on, off = (30, 20) if full else (5, 0)
    out.append(Case("all_muscles_step", "all ten muscles 0 -> 1 at once"
                    + (", held 0.3 s, then 1 -> 0, 0.2 s" if full else ", 0.05 s"),
                    scene_dict("all_muscles_step", MUSCLE_NAMES),
                    [(0.01, all_on)] * on + [(0.01, {m: 0.0 for m in MUSCLE_NAMES})] * off))
    # bang-bang antagonists at 20 Hz: OOP against RIS and ZYG, 5 ms communication steps
    n = 200 if full else 10
    steps = []
    for k in range(n):
        oop = (k // 5) % 2 == 0
        steps.append((0.005, {"OOP": float(oop), "RIS": float(not oop), "ZYG": float(not oop)}))
    out.append(Case("bang_bang_20hz", f"OOP against RIS + ZYG switched at 20 Hz for "
                    f"{n * 0.005:g} s, 5 ms steps", scene_dict("bang_bang_20hz",
                                                               ("OOP", "RIS", "ZYG")), steps,
                    halving_time=0.25 if full else None))
    # OOP + BUC at 1 with lip and teeth contact
    n = 200 if full else 4
    out.append(Case("oop_buc_contact", f"OOP + BUC at 1 with lip and teeth contact, "
                    f"{n * 0.005:g} s, 5 ms steps",
                    scene_dict("oop_buc_contact", ("OOP", "BUC")),
                    [(0.005, {"OOP": 1.0, "BUC": 1.0})] * n,
                    halving_time=0.25 if full else None))
    # communication steps of 0.1 ms (activations ramp to 0.7 over 10 ms)
    n = 500 if full else 3
    out.append(Case("tiny_steps", f"0.1 ms communication steps, OOP + BUC ramp to 0.7 "
                    f"over 10 ms, {n} steps", scene_dict("tiny_steps", ("OOP", "BUC"), "ramp"),
                    [(1e-4, {"OOP": _ramp((k + 1) * 1e-4, 0.01, 0.7),
                             "BUC": _ramp((k + 1) * 1e-4, 0.01, 0.7)}) for k in range(n)]))
    # communication steps of 100 ms
    pattern = [(0.7, 0.7), (0.0, 0.7), (0.7, 0.0), (1.0, 1.0), (0.0, 0.0)]
    n = 10 if full else 1
    out.append(Case("huge_steps", f"100 ms communication steps, OOP / BUC patterns, {n} steps",
                    scene_dict("huge_steps", ("OOP", "BUC"), "ramp"),
                    [(0.1, dict(zip(("OOP", "BUC"), pattern[k % len(pattern)])))
                     for k in range(n)]))
    # OOP + BUC + OOM held at 1 (lips pressed, cheeks drawn in): 100 ms steps, one 1 s step
    held = {"OOP": 1.0, "BUC": 1.0, "OOM": 1.0}
    n = 5 if full else 1
    out.append(Case("pressed_100ms_steps", f"OOP + BUC + OOM held at 1, {n} steps of 100 ms",
                    scene_dict("pressed_100ms_steps", tuple(held)), [(0.1, held)] * n))
    if full:
        out.append(Case("pressed_one_second_step", "OOP + BUC + OOM held at 1, one step of 1 s",
                        scene_dict("pressed_one_second_step", tuple(held)), [(1.0, held)]))
    # many consecutive 1 ms steps at rest: no drift, no memory growth
    n = 10_000 if full else 500
    out.append(Case("rest_1ms_steps", f"{n} consecutive 1 ms steps at rest",
                    scene_dict("rest_1ms_steps", MUSCLE_NAMES), [(0.001, {})] * n,
                    halving=False, rest=True, memory=True))
    if full:
        # many 1 ms steps under a held activation: settles on the static equilibrium
        out.append(Case("held_1ms_steps", "10000 consecutive 1 ms steps, OOP + BUC held "
                        "at 0.5: settles on the static equilibrium, never drifts away",
                        # contact off: the static reference solve stalls with lip contact
                        scene_dict("held_1ms_steps", ("OOP", "BUC"), lips=False, teeth=False),
                        [(0.001, {"OOP": 0.5, "BUC": 0.5})] * 10_000, halving=False,
                        memory=True, equilibrium=True))
        # random activation sequences of all ten muscles
        for seed in range(3):
            out.append(Case(f"random_{seed}", f"random activations of all ten muscles, "
                            f"10 steps of 2, 10 or 30 ms (seed {seed})",
                            scene_dict(f"random_{seed}", MUSCLE_NAMES, "ramp"),
                            random_steps(seed, 10)))
    # lips pressed shut (OOP + OOM at 1), then released within 10 ms, then at rest
    press = {"OOP": 1.0, "OOM": 1.0}
    n, m = (20, 20) if full else (4, 2)
    out.append(Case("pressed_released", f"lips pressed shut (OOP + OOM at 1) for "
                    f"{n * 5} ms, released to 0 over 10 ms, {m * 5} ms at rest",
                    scene_dict("pressed_released", ("OOP", "OOM"), "ramp"),
                    [(0.005, press)] * n + [(0.01, {})] + [(0.005, {})] * m))
    # lips pressed while pulled apart
    n = 40 if full else 4
    out.append(Case("pressed_pulled_apart", f"OOM + OOP at 1 against DLI + LLSAN at 1, "
                    f"{n * 5} ms in 5 ms steps",
                    scene_dict("pressed_pulled_apart", ("OOP", "OOM", "DLI", "LLSAN")),
                    [(0.005, {"OOP": 1.0, "OOM": 1.0, "DLI": 1.0, "LLSAN": 1.0})] * n))
    # all ten muscles switched at random every communication step of 1 to 20 ms
    for seed in range(3):
        n = 50 if full else 3
        out.append(Case(f"switching_{seed}", f"all ten muscles switched to random levels "
                        f"every step, {n} steps of 1 to 20 ms (seed {seed})",
                        scene_dict(f"switching_{seed}", MUSCLE_NAMES),
                        switching_steps(seed, n)))
    if full:
        # one communication step of 1 s
        out.append(Case("one_second_step", "a single 1 s communication step with the lips "
                        "pressed (OOP + OOM ramped to 1)",
                        scene_dict("one_second_step", ("OOP", "OOM"), "ramp"),
                        [(1.0, press)]))
    # the jaw opening and closing at 10 Hz (0 to 12 mm of incisor opening) while OOP and
    # OOM press the lips together, 5 ms steps
    n = 100 if full else 10
    theta = 2.0 * math.degrees(math.asin(6.0 / BONWILL_MM))
    out.append(Case("jaw_10hz_pressed", f"the jaw opening and closing at 10 Hz (0 to "
                    f"{theta:.2f} deg, 12 mm at the incisors) with OOP + OOM at 1, "
                    f"{n * 5} ms in 5 ms steps",
                    scene_dict("jaw_10hz_pressed", ("OOP", "OOM"), "ramp"),
                    [(0.005, {**press, "jaw_opening": 0.5 * theta * (
                        1.0 - math.cos(2.0 * math.pi * 10.0 * 0.005 * (k + 1)))})
                     for k in range(n)]))
    # rolled back and re-stepped at a contact-heavy point (lips pressed)
    n, r = (10, 1000) if full else (2, 5)
    out.append(Case("rollback_pressed", f"lips pressed (OOP + OOM at 1, {n * 5} ms), then "
                    f"the state restored and the last 5 ms step repeated {r} times",
                    scene_dict("rollback_pressed", ("OOP", "OOM")), [(0.005, press)] * n,
                    halving=False, rollback=r))
    # the clean failure mode: a step the solver cannot take is refused, state unchanged
    sc = scene_dict("refusal", ("OOP",), "ramp", max_substep=0.005, min_substep=0.004)
    sc["muscles"]["force_scale"] = {"OOP": 300.0}
    out.append(Case("refusal", "OOP at 300 x its force (inverts the tissue): the step is "
                    "refused with the state unchanged, the next small step works and "
                    "equals a run that never tried the refused one", sc,
                    [(0.005, {}), (0.005, {"OOP": 1.0}), (0.005, {"OOP": 0.0005})],
                    refused=(1,), halving=False))
    return out


def halved(scene, step=np.inf):
    """The scene's TOML sections with every substep halved (see the module docstring);
    step: the smallest communication step, which also bounds the substeps. A reduced
    model's substep (solver.rom.stepper.H_MAX, or the scene's max_substep) is halved too."""
    sc = parse_scene(scene)
    out = {k: dict(v) for k, v in scene.items()}
    out.setdefault("solver", {})
    largest = min(sc.max_substep, step, H_MAX if sc.fidelity in REDUCED else np.inf) / 2
    out["solver"]["substep_tol"] = sc.substep_tol / 4
    out["solver"]["max_substep"] = largest
    out["solver"]["min_substep"] = min(sc.min_substep, largest)
    return out


def to_toml(scene):
    """TOML text of scene sections (strings, booleans, numbers, lists, inline tables)."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, (int, float)):
            return repr(float(v)) if isinstance(v, float) else str(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        raise TypeError(f"cannot write {v!r} as TOML")
    lines = []
    for section, body in scene.items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {value(v)}" for k, v in body.items()]
        lines.append("")
    return "\n".join(lines)


# ------------------------------------------------------------------------ invariants

def min_det_f(mesh, u):
    """The smallest det F over all Gauss points of all bricks for displacements u (n, 3)."""
    grad = np.einsum("mai,mgaj->mgij", np.asarray(u, dtype=float)[mesh.bricks], mesh.dn_dx)
    return float(np.linalg.det(grad + np.eye(3)).min())


def point_triangle_distance(p, a, b, c):
    """(t,) distances of a point p (3,) to triangles with corners a, b, c (t, 3) each
    (Ericson, Real-Time Collision Detection 5.1.5, over all triangles at once)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp, cp = p - b, p - c
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v, w = vb / denom, vc / denom                               # inside the face
        q = a + v[:, None] * ab + w[:, None] * ac
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    cases = [  # (region mask, closest point), the first that holds wins
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[:, None] * ab),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[:, None] * ac),
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + t_bc[:, None] * (c - b)),
    ]
    done = np.zeros(len(a), dtype=bool)
    for mask, point in cases:
        take = mask & ~done
        q[take] = point[take]
        done |= take
    return np.linalg.norm(p - q, axis=1)


HEX_FACES = ((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7))


def brick_winding(xe, p):
    """The winding number of the brick xe (8, 3) (ANSYS node order) around the point p
    (3,): 1 inside, 0 outside; each face split into four triangles around its centroid
    (the solid angles of Van Oosterom and Strackee)."""
    total = 0.0
    for f in HEX_FACES:
        q = xe[list(f)] - p
        c = q.mean(axis=0)
        lc = np.linalg.norm(c)
        for i in range(4):
            a, b = q[i], q[(i + 1) % 4]
            la, lb = np.linalg.norm(a), np.linalg.norm(b)
            num = a @ np.cross(b, c)
            den = la * lb * lc + (a @ b) * lc + (b @ c) * la + (c @ a) * lb
            total += 2.0 * np.arctan2(num, den)
    return total / (4.0 * np.pi)


def inside_bricks(xe, p):
    """(m,) whether each point p (m, 3) lies inside its brick xe (m, 8, 3): natural
    coordinates within 1 - 1e-3 by Newton on the trilinear map; where Newton finds no
    root (a residual above 1e-7 mm: it can stop, clipped, inside the box), the brick's
    winding number decides (brick_winding)."""
    from solver.core.element import shape_functions, shape_gradients
    xi = np.zeros((len(p), 3))
    ok = np.ones(len(p), dtype=bool)
    for _ in range(25):
        r = np.einsum("pa,pai->pi", shape_functions(xi), xe) - p
        J = np.einsum("pai,paj->pij", xe, shape_gradients(xi))
        ok &= np.abs(np.linalg.det(J)) > 1e-12
        J[~ok] = np.eye(3)
        step = np.linalg.solve(J, -r[..., None])[..., 0]
        xi = np.clip(xi + step, -3.0, 3.0)
        if np.abs(step[ok]).max(initial=0.0) < 1e-10:
            break
    r = np.einsum("pa,pai->pi", shape_functions(xi), xe) - p
    solved = ok & (np.linalg.norm(r, axis=1) < 1e-7)
    hit = solved & np.all(np.abs(xi) < 1.0 - 1e-3, axis=1)
    for k in np.flatnonzero(~solved):
        hit[k] = brick_winding(xe[k], p[k]) > 0.5
    return hit


def face_sampling(n):
    """A bilinear face sampled by n x n sub-quads: weights (g, 4) of the (n + 1)^2 grid
    points over the face's corners, and the sub-quads' triangles (2 n^2, 3) over them."""
    g = np.linspace(-1.0, 1.0, n + 1)
    s, t = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    w = 0.25 * np.column_stack([(1 - s) * (1 - t), (1 + s) * (1 - t), (1 + s) * (1 + t),
                                (1 - s) * (1 + t)])
    k = np.arange(n + 1)[:, None] * (n + 1) + np.arange(n + 1)[None]
    a, b, c, d = k[:-1, :-1].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel(), k[:-1, 1:].ravel()
    return w, np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


class Probe:
    """Interpenetration of any state, measured outside every model.

    Lips: a node of a lip contact surface that lies inside a brick it does not belong to
    (natural coordinates within 1 - 1e-3, by Newton on the trilinear map; where Newton
    finds no root, the brick's winding number around the node) has entered
    tissue (the other lip, or its own lip folded over); its depth is its distance to the
    nearest lip-surface face it is not a corner of (the bilinear face, sampled by
    FACE_DIVISIONS^2 sub-quads: within a few thousandths of its warp). This sees what a contact term
    cannot: a node passing through triangles outside its candidate pairs. Teeth: the
    signed distances to the rigid teeth sheets of the nodes the model's teeth contact
    would hold (solver.face.terms.contact.build_contact_terms), by RigidContact terms that are
    in no model and search PROBE_DEPTH mm deep; with jaw (solver.face.jaw.Jaw, the model's),
    the lower teeth at its pose."""

    def __init__(self, anatomy, depth=PROBE_DEPTH, jaw=None):
        from solver.face.terms.contact import build_contact_terms
        mesh = anatomy.mesh
        self.mesh = mesh
        surf = anatomy.contact_surfaces
        faces = [f for k, f in surf.items() if k in ("upper_lip", "lower_lip")]
        self.nodes = np.unique(np.concatenate([f.ravel() for f in faces])) if faces else \
            np.zeros(0, dtype=np.int64)
        quads = [np.asarray(f) if np.asarray(f).shape[1] == 4 else
                 np.asarray(f)[:, [0, 1, 2, 2]] for f in faces]
        self.faces = np.vstack(quads) if faces else np.zeros((0, 4), dtype=np.int64)
        self._w, self._sub = face_sampling(FACE_DIVISIONS)
        self.teeth = []
        if anatomy.rigid_surfaces and surf:
            self.teeth = build_contact_terms(anatomy, lips=False, teeth=True,
                                             search_radius=depth, jaw=jaw)
        self._patterns = {id(t): Pattern(3 * mesh.n_nodes, t.blocks()) for t in self.teeth}
        self.inside = []          # (node, brick, depth) of the last lip measure

    def lip_overlap(self, u):
        """The deepest lip-surface node inside tissue it does not belong to (mm, 0 if
        none); the offenders in self.inside."""
        mesh = self.mesh
        self.inside = []
        if not len(self.nodes):
            return 0.0
        x = mesh.nodes + u
        xb = x[mesh.bricks]                                        # (m, 8, 3)
        lo, hi = xb.min(axis=1), xb.max(axis=1)
        p = x[self.nodes]
        near = np.all((lo[None] <= p[:, None] + 1e-9) & (p[:, None] <= hi[None] + 1e-9), axis=2)
        near &= ~(mesh.bricks[None, :, :] == self.nodes[:, None, None]).any(axis=2)
        ni, be = np.nonzero(near)
        if not len(ni):
            return 0.0
        hit = inside_bricks(xb[be], p[ni])
        worst = 0.0
        for k in np.flatnonzero(hit):
            node = int(self.nodes[ni[k]])
            depth = self.face_distance(x, node)
            self.inside.append((node, int(be[k]), depth))
            worst = max(worst, depth)
        return worst

    def face_distance(self, x, node):
        """The distance (mm) of node to the lip surfaces' bilinear faces it is not a
        corner of, at positions x (n, 3) (each face sampled by FACE_DIVISIONS^2
        sub-quads, two triangles each); only faces whose corners come within the
        nearest corner's distance plus the face's size are sampled."""
        f = self.faces[~(self.faces == node).any(axis=1)]
        xf = x[f]                                                      # (f, 4, 3)
        size = np.linalg.norm(xf - xf.mean(axis=1)[:, None], axis=2).max(axis=1)
        corner = np.linalg.norm(xf - x[node], axis=2).min(axis=1)
        f, xf = f[corner - size <= (corner + size).min()], xf[corner - size <= (corner + size).min()]
        pts = np.einsum("ga,fai->fgi", self._w, xf)                   # (f, g, 3)
        tri = pts[:, self._sub].reshape(-1, 3, 3)
        area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        tri = tri[area > 1e-12]                         # a degenerate quad's collapsed rows
        return float(point_triangle_distance(x[node], tri[:, 0], tri[:, 1], tri[:, 2]).min())

    def teeth_penetration(self, u):
        """The deepest lip-into-teeth penetration (mm, >= 0)."""
        worst = 0.0
        for t in self.teeth:
            pattern = self._patterns[id(t)]
            t.assemble(State(u), Assembly(pattern, False), list(range(len(pattern.dofs))))
            worst = max(worst, t.max_penetration)
        return worst

    def penetrations(self, u):
        """(lips, teeth) deepest penetrations (mm, >= 0) at displacements u (n, 3)."""
        u = np.asarray(u, dtype=float).reshape(-1, 3)
        return self.lip_overlap(u), self.teeth_penetration(u)


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


# ------------------------------------------------------------------------ through the FMU

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
