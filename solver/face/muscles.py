"""Muscle constants: cable force law, peak forces and activation stiffening, with sources.

Cables (ANSYS LINK10 in the original): tension only,

    T = A E (eps - alpha dT)  if positive, else 0,     eps = l / L0 - 1,

with the activation a in [0, 1] driving the virtual temperature drop,
alpha dT = -a s F_max / (A E), so that T = s F_max at a = 1 and eps = 0 (s: the user's
per-muscle force scale, default 1). The force falls linearly as the cable shortens and
vanishes at eps = -a s F_max / (A E) = -a s eps_c.

Constants of the `physiological` calibration, the default (DEFAULT_CALIBRATION; the
`paper` calibration replaces sigma_max, eps_c and the stiffening factor: calibrated
below):
* Peak force per fibre F_max = sigma_max * pi r^2: the maximum stress of skeletal muscle
  times the muscle's cross-section, a circle of the muscle's radius r (the same r that
  bounds its stiffened neighbourhood, below).
  - sigma_max = 0.1 MPa (100 kPa): the maximum stress of the element-based face muscles
    in ArtiSynth Models' face demos (which read this same ANSYS model).
  - r: 2 mm for ZYG and 3 mm for OOP (the paper's Figure 6); the others are estimates of
    the same order (table STIFFENING_RADIUS_MM). So F_max is 2.83 N for OOP and BUC, 1.26 N
    for ZYG, LLSAN and LAO, 0.71 N for RIS: of the order of the 1 N per fibre that
    published face models use (ArtiSynth's point-to-point face muscles default to 1.0 N).
  The cable's cross-section is that same A = pi r^2, so the cable stress at peak force
  is sigma_max.
* eps_c = 0.5: the cable goes slack at full activation after shortening by half (the
  active force-length range of skeletal muscle); so E = sigma_max / eps_c = 0.2 MPa.

Activation stiffening (the paper's Figure 7): bricks within radius r of a fibre get c10
and c20 multiplied by k(a) = 1 + a (E_c / E_0 - 1), linear in activation from the
tissue's own initial Young's modulus E_0 = 6 c10 = 15 kPa (the paper's E) at rest to the
contracted Young's modulus of skeletal muscle E_c = 110 kPa (Duck, Physical Properties of
Tissue, 1990) at a = 1: k(1) = 7.33. (Duck's relaxed-muscle modulus, 6.2 kPa, is below
the paper's tissue modulus; the law starts from the tissue the model actually has.) A
brick near two muscles takes the larger factor. By default a brick's factor is weighted
by the fraction of its volume inside the radius (stiffening_rule "volume"; "intersect" is
the paper's whole-brick rule; solver/face/terms/stiffening.py says why).
"""

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.core.errors import ParameterError

SIGMA_MAX_MPA = 0.1
PAPER_FILE = Path(__file__).parent / "data" / "paper_calibration.json"
EPS_CONTRACTION = 0.5
E_TISSUE_KPA = 15.0          # 6 c10, the paper's E
E_CONTRACTED_KPA = 110.0

STIFFENING_RADIUS_MM = {"LLSAN": 2.0, "LAO": 2.0, "ZYG": 2.0, "RIS": 1.5, "BUC": 3.0,
                        "DAO": 2.5, "DLI": 2.5, "MENT": 2.5, "OOP": 3.0, "OOM": 2.0}


def peak_force(radius_mm, sigma_max=SIGMA_MAX_MPA):
    """F_max (N) of a fibre of radius r (mm): sigma_max pi r^2."""
    return sigma_max * math.pi * radius_mm ** 2


F_MAX_N = {m: peak_force(r) for m, r in STIFFENING_RADIUS_MM.items()}


def paper_calibration():
    """The identification record of the `paper` calibration (a dict: sigma_max_mpa, the
    objective, the rows fitted, provenance), as written by
    `python benchmarks/calibrate_paper.py`."""
    try:
        rec = json.loads(PAPER_FILE.read_text())
        {k: float(rec["constants"][k]) for k in ("sigma_max", "eps_contraction",
                                                   "stiffening_max")}
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ParameterError(f"{PAPER_FILE}: not a paper calibration record ({err!r}); "
                             "`python benchmarks/calibrate_paper.py` writes it") from None
    return rec


def calibrated(name):
    """The muscle constants of the named calibration, dict(sigma_max (MPa),
    eps_contraction, stiffening_max):

    physiological  sigma_max 0.1 MPa, the maximum stress of skeletal muscle, eps_c 0.5 and
                   stiffening up to E_c / E_0 = 7.33 (above)
    paper          identified so that the reference face reproduces the paper's Table 4
                   (OOP's largest compressive strain over a 0.1 s activation ramp):
                   solver/face/data/paper_calibration.json, docs/table4.md
    """
    if name == "physiological":
        return {"sigma_max": SIGMA_MAX_MPA, "eps_contraction": EPS_CONTRACTION,
                "stiffening_max": E_CONTRACTED_KPA / E_TISSUE_KPA}
    if name == "paper":
        return {k: float(v) for k, v in paper_calibration()["constants"].items()}
    raise ParameterError(f"muscle calibration {name!r} is not one of {list(CALIBRATIONS)}")


CALIBRATIONS = ("physiological", "paper")
DEFAULT_CALIBRATION = "physiological"


def _per_muscle(value):
    return field(default_factory=lambda: {m: value for m in MUSCLE_NAMES})


@dataclass
class MuscleProperties:
    """Per-muscle constants (dicts keyed by MUSCLE_NAMES). sigma_max, eps_contraction and
    stiffening_max default to the named calibration's (``calibrated``; by default
    DEFAULT_CALIBRATION, ``physiological``); f_max defaults to sigma_max pi r^2 over the stiffening radii (one stress
    for all ten muscles)."""

    f_max: dict = None                                  # N per fibre at a = 1
    force_scale: dict = _per_muscle(1.0)                # user scale of the active force
    calibration: str = DEFAULT_CALIBRATION              # gives the three constants below
    sigma_max: float = None                             # MPa
    eps_contraction: float = None
    stiffening_max: float = None
    stiffening_radius: dict = field(default_factory=lambda: dict(STIFFENING_RADIUS_MM))
    stiffening_rule: str = "volume"                     # or "intersect" (solver.face.terms.stiffening)

    def __post_init__(self):
        for name, value in calibrated(self.calibration).items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        if not (isinstance(self.sigma_max, (int, float)) and 0 < self.sigma_max < math.inf):
            raise ParameterError(f"sigma_max = {self.sigma_max!r} must be a finite number > 0 "
                                 "(MPa)")
        self._check_per_muscle("stiffening_radius")
        if self.f_max is None:
            self.f_max = {m: peak_force(r, self.sigma_max)
                          for m, r in self.stiffening_radius.items()}
        self._check_per_muscle("f_max")
        self._check_per_muscle("force_scale")
        if not (isinstance(self.eps_contraction, (int, float))
                and 0 < self.eps_contraction < math.inf):
            raise ParameterError(f"eps_contraction = {self.eps_contraction!r} must be a "
                                 "finite number > 0")
        if self.stiffening_rule not in ("volume", "intersect"):
            raise ParameterError(f"stiffening_rule = {self.stiffening_rule!r} is not one of "
                                 "['volume', 'intersect']")
        if not (isinstance(self.stiffening_max, (int, float))
                and 1.0 <= self.stiffening_max < math.inf):
            raise ParameterError(f"stiffening_max = {self.stiffening_max!r} must be a "
                                 "finite number >= 1")

    def _check_per_muscle(self, name):
        d = getattr(self, name)
        unknown = set(d) - set(MUSCLE_NAMES)
        if unknown:
            raise ParameterError(f"{name}: unknown muscle(s) {sorted(unknown)}; "
                                 f"known: {list(MUSCLE_NAMES)}")
        for m, v in d.items():
            if not (isinstance(v, (int, float)) and v >= 0 and v == v and v != float("inf")):
                raise ParameterError(f"{name}[{m}] = {v!r} must be a finite number >= 0")

    def area(self, muscle):
        """Cable cross-section A (mm^2)."""
        return self.f_max[muscle] / self.sigma_max

    def youngs_modulus(self):
        """Cable E (MPa)."""
        return self.sigma_max / self.eps_contraction

    def active_strain(self, muscle, a):
        """-alpha dT for activation a: the strain offset a s F_max / (A E)."""
        return a * self.force_scale[muscle] * self.eps_contraction

    def stiffening_factor(self, a):
        return 1.0 + a * (self.stiffening_max - 1.0)
