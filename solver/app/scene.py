"""Scenes: what a study simulates, in a small TOML file, validated with clear errors.

A scene names the anatomy, the driven muscles (the others are not assembled), the effects
(each one a solver term, built only when asked for), the analysis, tolerances, the
recorded outputs and, for standalone runs, activation schedules. Its TOML sections and
keys (one `Scene` field per key, whose defaults are the fields'; units mm, s, MPa):

    [scene]      name, description, analysis ("static" | "transient"), duration (s),
                 fidelity: a preset of solver.app.fidelity (fast | balanced | accurate;
                 keys written in the file win) or "realtime", the reduced model (solver.rom)
    [anatomy]    source ("generic" or an ANSYS face folder), level (coarse | medium |
                 paper | fine), half (x <= 0, u_x = 0 on the mid-sagittal plane),
                 rows (brick rows per layer of the generic face, 1-4)
    [muscles]    driven (default all ten), force_scale {muscle: scale}, calibration
                 ("physiological" | "paper": solver.face.muscles.calibrated), and, each
                 replacing the calibration's, sigma_max (MPa), contraction_strain (eps_c),
                 stiffening_max (the stiffening factor at a = 1)
    [effects]    inertia, damping (transient only), stiffening, stiffening_rule ("volume" |
                 "intersect"), lip_contact, teeth_contact (false lets lips and teeth
                 interpenetrate), gravity ("none" | "upright": -z | "supine": -y)
    [gravity]    g (m/s^2)
    [damping]    alpha (1/s), beta (s), density (kg/m^3): C = alpha M + beta K_n
    [solver]     formulation ("mean_dilatation" | "full"), linear_solver ("auto" |
                 "pardiso-single" | "pardiso" | "superlu"), newton_rtol, newton_utol (mm),
                 lip_penalty (N/mm^3), integrator ("backward_euler" | "bdf2"), substep_tol
                 (mm) and substep_rtol (a substep is kept when every local error is at most
                 substep_tol + substep_rtol |u|), max_substep, min_substep (s), hold
                 (activations within a step: "ramp" | "step")
    [outputs]    record (names from OUTPUTS), interval (s, standalone runs)
    [[schedule]] muscle = "OOP", or jaw = "opening" (deg) | "protrusion" (mm, JAW_RANGES);
                 kind "ramp" (start, end, from, to) | "step" (time, value) | "pwl" (times,
                 values); activations are 0 and the jaw closed where unset

"muscle_strains" records strain_min_M and strain_max_M (M a muscle): the most compressive
and most tensile logarithmic principal strain over each driven muscle's region (its
stiffening neighbourhood). A run with gravity starts from the static equilibrium under
gravity alone; the lip outputs stay measured from the mesh as given.

Every key annotated, in an example scene: docs/method.md, section 'Scene files'.
"""

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.core.errors import FaceFMUError
from solver.app.fidelity import FIDELITIES, REDUCED, fidelity_overrides
from solver.face.jaw import JAW_RANGES
from solver.core.linsolve import SOLVERS
from solver.face.muscles import CALIBRATIONS, DEFAULT_CALIBRATION, calibrated
from solver.face.terms.contact import PENALTY

ANALYSES = ("static", "transient")
LEVELS = ("coarse", "medium", "paper", "fine")
GRAVITY = {"none": None, "upright": (0.0, 0.0, -1.0), "supine": (0.0, -1.0, 0.0)}
OUTPUTS = ("lip_aperture", "lip_protrusion", "lip_width", "upper_lip_protrusion",
           "lower_lip_protrusion", "contact_force", "newton_iterations", "substeps",
           "cutbacks", "muscle_strains")
SCHEDULE_KINDS = ("step", "ramp", "pwl")


class SceneError(FaceFMUError, ValueError):
    """A scene that cannot be used; names the file and the key."""

    def __init__(self, source, key, message):
        self.source, self.key = str(source), key
        super().__init__(f"{source}: [{key}] {message}")


@dataclass(frozen=True)
class Schedule:
    """A schedule of one input: a muscle's activation (value(t) in [0, 1]) or a jaw
    input ('jaw_opening' deg, 'jaw_protrusion' mm, in solver.face.jaw.JAW_RANGES)."""

    muscle: str
    kind: str
    times: tuple
    values: tuple

    def value(self, t):
        return float(np.interp(t, self.times, self.values)) if self.kind != "step" else \
            float(self.values[1] if t >= self.times[0] else self.values[0])


@dataclass(frozen=True)
class Scene:
    """A scene: what to simulate and how (the TOML sections of the module docstring, one
    field per key; schedules: Schedule tuple). Frozen: with_overrides returns a copy."""

    name: str = "custom"
    description: str = ""
    analysis: str = "transient"
    duration: float = 0.3
    anatomy: str = "generic"
    level: str = "coarse"
    half: bool = True
    rows: int = None
    driven: tuple = MUSCLE_NAMES
    force_scale: dict = field(default_factory=dict)
    calibration: str = DEFAULT_CALIBRATION
    sigma_max: float = None
    contraction_strain: float = None
    stiffening_max: float = None
    inertia: bool = True
    damping: bool = True
    stiffening: bool = True
    stiffening_rule: str = "volume"
    lip_contact: bool = True
    teeth_contact: bool = True
    gravity: str = "none"
    g: float = 9.81
    alpha: float = 40.0
    beta: float = 0.03
    density: float = 1040.0
    formulation: str = "mean_dilatation"
    linear_solver: str = "auto"
    newton_rtol: float = 1e-6
    newton_utol: float = 1e-5
    lip_penalty: float = PENALTY
    integrator: str = "backward_euler"
    substep_tol: float = 1e-3
    substep_rtol: float = 0.0
    max_substep: float = 5e-3
    min_substep: float = 1e-7
    hold: str = "ramp"
    record: tuple = ("lip_aperture", "lip_protrusion", "lip_width")
    interval: float = 0.005
    schedules: tuple = ()
    fidelity: str = ""              # the file's named fidelity ("realtime": the ROM)

    @property
    def effects(self):
        """The effects this scene calls for, by term name."""
        on = ["elasticity"]
        if self.driven:
            on.append("cables")
            if self.stiffening:
                on.append("stiffening")
        if self.analysis == "transient":
            on += [n for n, f in (("inertia", self.inertia), ("damping", self.damping)) if f]
        on += [n for n, f in (("lip_contact", self.lip_contact),
                              ("teeth_contact", self.teeth_contact)) if f]
        if self.gravity != "none":
            on.append("gravity")
        return on

    def contact_warnings(self):
        """Sentences naming the paper's contacts that this scene leaves out (empty when it
        has lip/lip and lip/teeth contact)."""
        off = [n for n, on in (("lip/lip", self.lip_contact), ("lip/teeth", self.teeth_contact))
               if not on]
        if not off:
            return []
        return [f"scene '{self.name}' leaves out {' and '.join(off)} contact: lips and teeth "
                "can interpenetrate"]

    def activations(self, t):
        """dict muscle -> activation at time t from the schedules (0 where unset)."""
        out = {m: 0.0 for m in self.driven}
        for s in self.schedules:
            if s.muscle not in JAW_RANGES:
                out[s.muscle] = s.value(t)
        return out

    def jaw(self, t):
        """dict jaw input -> value at time t from the jaw schedules ({} without any)."""
        return {s.muscle: s.value(t) for s in self.schedules if s.muscle in JAW_RANGES}

    def muscle_constants(self):
        """dict(sigma_max (MPa), eps_contraction, stiffening_max) of the muscles: the named
        calibration's (solver.face.muscles.calibrated), with sigma_max, contraction_strain and
        stiffening_max where the scene gives them."""
        out = calibrated(self.calibration)
        for key, field_name in (("sigma_max", "sigma_max"),
                                ("eps_contraction", "contraction_strain"),
                                ("stiffening_max", "stiffening_max")):
            if getattr(self, field_name) is not None:
                out[key] = float(getattr(self, field_name))
        return out

    def with_overrides(self, **kw):
        return replace(self, **kw)


# section -> {key: (Scene field, validator)}
def _choice(allowed):
    def check(v):
        if v not in allowed:
            raise ValueError(f"{v!r} is not one of {list(allowed)}")
        return v
    return check


def _bool(v):
    if not isinstance(v, bool):
        raise ValueError(f"{v!r} is not true or false")
    return v


def _number(lo=None, hi=None, strict_lo=False):
    def check(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{v!r} is not a finite number")
        if lo is not None and (v <= lo if strict_lo else v < lo):
            raise ValueError(f"{v!r} must be {'>' if strict_lo else '>='} {lo}")
        if hi is not None and v > hi:
            raise ValueError(f"{v!r} must be <= {hi}")
        return float(v)
    return check


def _integer(lo, hi):
    def check(v):
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise ValueError(f"{v!r} is not an integer from {lo} to {hi}")
        return v
    return check


def _string(v):
    if not isinstance(v, str):
        raise ValueError(f"{v!r} is not a string")
    return v


def _muscles(v):
    if not isinstance(v, list) or any(m not in MUSCLE_NAMES for m in v):
        raise ValueError(f"{v!r} must be a list of muscles among {list(MUSCLE_NAMES)}")
    return tuple(m for m in MUSCLE_NAMES if m in v)


def _scales(v):
    if not isinstance(v, dict):
        raise ValueError(f"{v!r} must be a table muscle = scale")
    for m, s in v.items():
        if m not in MUSCLE_NAMES:
            raise ValueError(f"unknown muscle {m!r}; known: {list(MUSCLE_NAMES)}")
        _number(0.0)(s)
    return dict(v)


def _outputs(v):
    if not isinstance(v, list) or any(o not in OUTPUTS for o in v):
        raise ValueError(f"{v!r} must be a list among {list(OUTPUTS)}")
    return tuple(v)


SECTIONS = {
    "scene": {"name": ("name", _string), "description": ("description", _string),
              "analysis": ("analysis", _choice(ANALYSES)),
              "duration": ("duration", _number(0.0, strict_lo=True)),
              "fidelity": ("fidelity", _choice(FIDELITIES + tuple(REDUCED)))},
    "anatomy": {"source": ("anatomy", _string), "level": ("level", _choice(LEVELS)),
                "half": ("half", _bool), "rows": ("rows", _integer(1, 4))},
    "muscles": {"driven": ("driven", _muscles), "force_scale": ("force_scale", _scales),
                "calibration": ("calibration", _choice(CALIBRATIONS)),
                "sigma_max": ("sigma_max", _number(0.0, 10.0, strict_lo=True)),
                "contraction_strain": ("contraction_strain", _number(0.0, 10.0, strict_lo=True)),
                "stiffening_max": ("stiffening_max", _number(1.0, 100.0))},
    "effects": {"inertia": ("inertia", _bool), "damping": ("damping", _bool),
                "stiffening": ("stiffening", _bool), "lip_contact": ("lip_contact", _bool),
                "stiffening_rule": ("stiffening_rule", _choice(("volume", "intersect"))),
                "teeth_contact": ("teeth_contact", _bool),
                "gravity": ("gravity", _choice(tuple(GRAVITY)))},
    "gravity": {"g": ("g", _number(0.0))},
    "damping": {"alpha": ("alpha", _number(0.0)), "beta": ("beta", _number(0.0)),
                "density": ("density", _number(0.0))},
    "solver": {"formulation": ("formulation", _choice(("mean_dilatation", "full"))),
               "linear_solver": ("linear_solver", _choice(SOLVERS)),
               "newton_rtol": ("newton_rtol", _number(0.0, 1e-1, strict_lo=True)),
               "newton_utol": ("newton_utol", _number(0.0, 1.0, strict_lo=True)),
               "lip_penalty": ("lip_penalty", _number(0.0, 1e3, strict_lo=True)),
               "integrator": ("integrator", _choice(("bdf2", "backward_euler"))),
               "substep_tol": ("substep_tol", _number(0.0, strict_lo=True)),
               "substep_rtol": ("substep_rtol", _number(0.0, 1.0)),
               "max_substep": ("max_substep", _number(0.0, strict_lo=True)),
               "min_substep": ("min_substep", _number(0.0, strict_lo=True)),
               "hold": ("hold", _choice(("ramp", "step")))},
    "outputs": {"record": ("record", _outputs),
                "interval": ("interval", _number(0.0, strict_lo=True))},
}


def _schedule(source, i, item, driven):
    key = f"schedule.{i}"
    if not isinstance(item, dict):
        raise SceneError(source, key, "must be a table")
    allowed = {"muscle", "jaw", "kind", "start", "end", "from", "to", "time", "value",
               "times", "values"}
    unknown = set(item) - allowed
    if unknown:
        raise SceneError(source, f"{key}.{sorted(unknown)[0]}",
                         f"unknown key; allowed: {sorted(allowed)}")
    try:
        if ("jaw" in item) == ("muscle" in item):
            raise ValueError("give either muscle or jaw")
        if "jaw" in item:
            muscle = "jaw_" + _choice(tuple(k[4:] for k in JAW_RANGES))(item["jaw"])
            unit = _number(*JAW_RANGES[muscle])
        else:
            muscle = _choice(driven)(item.get("muscle"))
            unit = _number(0.0, 1.0)
        kind = _choice(SCHEDULE_KINDS)(item.get("kind"))
        if kind == "step":
            times, values = (_number(0.0)(item["time"]),), (0.0, unit(item["value"]))
        elif kind == "ramp":
            t0, t1 = _number(0.0)(item["start"]), _number(0.0)(item["end"])
            if t1 <= t0:
                raise ValueError(f"end {t1} must be after start {t0}")
            times, values = (t0, t1), (unit(item.get("from", 0.0)), unit(item["to"]))
        else:
            times = tuple(_number(0.0)(t) for t in item["times"])
            values = tuple(unit(v) for v in item["values"])
            if len(times) != len(values) or len(times) < 2 or np.any(np.diff(times) <= 0):
                raise ValueError("times must increase and match values (at least two)")
    except KeyError as exc:
        raise SceneError(source, f"{key}.{exc.args[0]}", "missing") from None
    except (ValueError, TypeError) as exc:
        raise SceneError(source, key, str(exc)) from None
    return Schedule(muscle, kind, times, values)


def parse_scene_schedule(item, scene, source="<command line>"):
    """One Schedule from a [[schedule]] table (dict) for a Scene (its driven muscles);
    SceneError naming the source and key where it cannot be used."""
    return _schedule(source, len(scene.schedules), item, scene.driven)


def parse_scene(data, source="<scene>"):
    """A Scene from a dict (parsed TOML); errors name the source and the key."""
    if not isinstance(data, dict):
        raise SceneError(source, "", "a scene is a table of sections")
    allowed = set(SECTIONS) | {"schedule"}
    values = {}
    for section, body in data.items():
        if section not in allowed:
            raise SceneError(source, section, f"unknown section; allowed: {sorted(allowed)}")
        if section == "schedule":
            continue
        if not isinstance(body, dict):
            raise SceneError(source, section, "must be a table")
        for key, v in body.items():
            spec = SECTIONS[section].get(key)
            if spec is None:
                raise SceneError(source, f"{section}.{key}",
                                 f"unknown key; allowed: {sorted(SECTIONS[section])}")
            try:
                values[spec[0]] = spec[1](v)
            except ValueError as exc:
                raise SceneError(source, f"{section}.{key}", str(exc)) from None
    if "fidelity" in values:                       # the preset under the file's own keys
        name = values.pop("fidelity")
        values = (fidelity_overrides(name, values.get("anatomy", "generic")) | values
                  | {"fidelity": name})
    scene = Scene(**values)
    items = data.get("schedule", [])
    if not isinstance(items, list):
        raise SceneError(source, "schedule", "must be an array of tables [[schedule]]")
    scheds = tuple(_schedule(source, i, it, scene.driven) for i, it in enumerate(items))
    scene = replace(scene, schedules=scheds)
    if scene.min_substep > scene.max_substep:
        raise SceneError(source, "solver.min_substep", "must be <= max_substep")
    return scene


def load_scene(path):
    """A Scene from a TOML file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SceneError(path, "", f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise SceneError(path, "", f"not a text file (byte {exc.start} is not UTF-8)") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(path, "", f"not valid TOML: {exc}") from None
    scene = parse_scene(data, path)
    return scene if "name" in data.get("scene", {}) else replace(scene, name=path.stem)

