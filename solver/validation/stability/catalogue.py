"""The hard cases: what a case is, and the catalogue of them, read from cases.toml.

A case is a scene, written as TOML sections in a dict (so that the same case runs in
this process through Simulation and through the FMU as a scene file), and a list of
communication steps (step size s, activations): a master's loop, which sets the
activations and then takes the step (with the scene's hold: "step" jumps at the start of
the step, "ramp" ramps over it), plus flags saying which further checks the case gets
(Case). ``cases(full)`` lists them: the quick versions (CI) or the full ones (the stress
run); the quick versions are short cuts of the full.

The catalogue is data (cases.toml next to this module), so that a case is read, changed
or added as a table rather than as code: each names its scene builder (SCENE_BUILDERS)
with the builder's arguments, and its schedule as a kind (SCHEDULES) with parameters
(counts, step sizes, seeds), never as the expanded steps; ``cases`` expands them into the
same Case objects every time. ``configured`` moves a case to another anatomy, level or
fidelity; ``halved`` is the scene the convergence check runs (runner.halving_limit);
``to_toml`` writes a scene as a scene file (for the FMU).
"""

import copy
import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from solver.app.fidelity import REDUCED
from solver.app.scene import parse_scene
from solver.face.anatomy.base import MUSCLE_NAMES
from solver.face.jaw import BONWILL_MM
from solver.rom.stepper import H_MAX

CATALOGUE = Path(__file__).with_name("cases.toml")


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
        """The case with every substep halved (halved(scene)), over its first
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


def halved(scene, step=np.inf):
    """The scene's TOML sections with every substep halved: substep_tol / 4 and
    max_substep halved (runner's docstring); step: the smallest communication step, which
    also bounds the substeps. A reduced model's substep (solver.rom.stepper.H_MAX, or the
    scene's max_substep) is halved too."""
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


# ------------------------------------------------------------------------ schedules

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


def _muscles(names):
    """A schedule's or scene's muscles: "all" is every muscle (MUSCLE_NAMES)."""
    return MUSCLE_NAMES if names == "all" else tuple(names)


def _levels(activations=None, all_muscles=None):
    """A step's activations: {muscle: a}, or all_muscles: every muscle at that level."""
    if all_muscles is not None:
        return {m: float(all_muscles) for m in MUSCLE_NAMES}
    return {m: float(a) for m, a in (activations or {}).items()}


def hold_steps(seed, step, count, activations=None):
    """count steps of step s, the activations held (none: every muscle at 0)."""
    return [(float(step), _levels(activations))] * count


def segment_steps(seed, segments, counts):
    """Segments one after the other: counts[i] steps of segments[i] ({step, activations}
    or {step, all_muscles})."""
    out = []
    for seg, n in zip(segments, counts, strict=True):
        seg = dict(seg)
        out += [(float(seg.pop("step")), _levels(**seg))] * n
    return out


def bang_bang_steps(seed, step, count, switch_every, on, against):
    """on at 1 and against at 0, swapped every switch_every steps (on first)."""
    out = []
    for k in range(count):
        first = (k // switch_every) % 2 == 0
        out.append((float(step), {**{m: float(first) for m in on},
                                  **{m: float(not first) for m in against}}))
    return out


def _ramp(t, t_full, value):
    return value * min(1.0, t / t_full)


def ramp_steps(seed, step, count, muscles, level, over):
    """count steps of step s, muscles ramped from 0 to level over `over` s (the value at
    the end of each step)."""
    return [(float(step), {m: _ramp((k + 1) * step, over, level) for m in muscles})
            for k in range(count)]


def cycle_steps(seed, step, count, muscles, levels):
    """count steps of step s, muscles at levels[k % len(levels)] in step k."""
    return [(float(step), dict(zip(muscles, (float(a) for a in levels[k % len(levels)]))))
            for k in range(count)]


def jaw_opening_deg(incisor_opening):
    """The jaw's opening angle (deg) for an incisor opening (mm) on the Bonwill triangle."""
    return 2.0 * math.degrees(math.asin(0.5 * incisor_opening / BONWILL_MM))


def jaw_steps(seed, step, count, frequency, incisor_opening, activations):
    """count steps of step s, activations held, the jaw opening from 0 to incisor_opening
    mm at the incisors and closing again at frequency Hz (the value at each step's end)."""
    theta, acts = jaw_opening_deg(incisor_opening), _levels(activations)
    return [(float(step), {**acts, "jaw_opening": 0.5 * theta * (
        1.0 - math.cos(2.0 * math.pi * frequency * step * (k + 1)))}) for k in range(count)]


def _random(seed, segments, sizes, muscles="all"):
    return random_steps(seed, segments, _muscles(muscles), tuple(sizes))


def _switching(seed, count, shortest, longest, muscles="all"):
    return switching_steps(seed, count, _muscles(muscles), shortest, longest)


# a schedule's kind -> its steps from (seed, **its parameters in cases.toml)
SCHEDULES = {"hold": hold_steps, "segments": segment_steps, "bang_bang": bang_bang_steps,
             "ramp": ramp_steps, "cycle": cycle_steps, "jaw": jaw_steps,
             "random": _random, "switching": _switching}

# a scene's builder -> (name, **its arguments in cases.toml) -> TOML sections
SCENE_BUILDERS = {"scene_dict": scene_dict}

_FLAGS = ("refused", "halving", "rest", "memory", "equilibrium", "halving_time", "rollback")
_CASE_KEYS = {"name", "description", "seeds", "scene", "schedule", "quick", "full", *_FLAGS}
_VERSION_KEYS = {"description", "schedule", *_FLAGS}


# ---------------------------------------------------------------------------- cases

def _scene(name, spec):
    """A case's scene from its cases.toml table: the builder's sections, then merge's."""
    args = copy.deepcopy(spec)
    build, merge = SCENE_BUILDERS[args.pop("builder")], args.pop("merge", {})
    args["driven"], solver = _muscles(args["driven"]), args.pop("solver", {})
    scene = build(name, **args, **solver)
    for section, body in merge.items():
        scene.setdefault(section, {}).update(body)
    return scene


def _build(entry, version, seed):
    """The Case of a cases.toml table in one version (quick or full) for one seed."""
    for keys, table, what in ((_CASE_KEYS, entry, "case"),
                              (_VERSION_KEYS, version, "version")):
        if set(table) - keys:
            raise ValueError(f"{CATALOGUE}: {entry['name']}: unknown {what} keys "
                             f"{sorted(set(table) - keys)}")
    spec = {**entry, **version, "schedule": {**entry["schedule"], **version.get("schedule", {})}}
    params = dict(spec["schedule"])
    kind = params.pop("kind")
    fields = {"seed": seed}
    if kind == "jaw":
        fields["opening_deg"] = jaw_opening_deg(params["incisor_opening"])
    name = spec["name"].format(**fields)
    flags = {k: spec[k] for k in _FLAGS if k in spec}
    if "refused" in flags:
        flags["refused"] = tuple(flags["refused"])
    return Case(name, spec["description"].format(**fields), _scene(name, spec["scene"]),
                SCHEDULES[kind](seed, **params), **flags)


def cases(full=False):
    """The hard cases: quick versions (CI) or the full ones (the stress run), from
    cases.toml."""
    with open(CATALOGUE, "rb") as fh:
        catalogue = tomllib.load(fh)
    which = "full" if full else "quick"
    return [_build(entry, entry[which], seed) for entry in catalogue["case"] if which in entry
            for seed in entry.get("seeds", [None])]
