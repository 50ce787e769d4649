"""Muscle constants: cable force law, peak forces and activation stiffening, with sources.

Cables (ANSYS LINK10 in the original): tension only,

    T = A E (eps - alpha dT)  if positive, else 0,     eps = l / L0 - 1,

with the activation a in [0, 1] driving the virtual temperature drop,
alpha dT = -a s F_max / (A E), so that T = s F_max at a = 1 and eps = 0 (s: the user's
per-muscle force scale, default 1). The force falls linearly as the cable shortens and
vanishes at eps = -a s F_max / (A E) = -a s eps_c.

Constants (defaults; every one is a parameter of MuscleProperties):
* F_max = 1.0 N per fibre: the default maximum force of the face model's muscle segments
  in ArtiSynth Models' face demos (which read this same ANSYS model); face models use
  forces of the order of 1 N per fibre.
* sigma_max = 0.1 MPa (100 kPa): the maximum muscle stress of ArtiSynth's element-based
  face muscles; it sets the cable's cross-section A = F_max / sigma_max = 10 mm^2
  (radius 1.8 mm, the order of the 2-3 mm stiffening radii of the paper's Figure 6).
* eps_c = 0.5: the cable goes slack at full activation after shortening by half (the
  active force-length range of skeletal muscle); so E = sigma_max / eps_c = 0.2 MPa.

Activation stiffening (the paper's Figure 7): bricks within radius r of a fibre get c10
and c20 multiplied by k(a) = 1 + a (E_c / E_r - 1), linear between the relaxed and the
contracted Young's modulus of skeletal muscle, E_r = 6.2 kPa and E_c = 110 kPa (Duck,
Physical Properties of Tissue, 1990): k(1) = 17.7. A brick near two muscles takes the
larger factor. Radii per muscle, of the order of the muscle's cross-section: 2 mm for
ZYG and 3 mm for OOP (the paper's Figure 6), and estimates for the others.
"""

from dataclasses import dataclass, field

from .anatomy.base import MUSCLE_NAMES
from .errors import ParameterError

F_MAX_N = 1.0
SIGMA_MAX_MPA = 0.1
EPS_CONTRACTION = 0.5
E_RELAXED_KPA = 6.2
E_CONTRACTED_KPA = 110.0

STIFFENING_RADIUS_MM = {"LLSAN": 2.0, "LAO": 2.0, "ZYG": 2.0, "RIS": 1.5, "BUC": 3.0,
                        "DAO": 2.5, "DLI": 2.5, "MENT": 2.5, "OOP": 3.0, "OOM": 2.0}


def _per_muscle(value):
    return field(default_factory=lambda: {m: value for m in MUSCLE_NAMES})


@dataclass
class MuscleProperties:
    """Per-muscle constants (dicts keyed by MUSCLE_NAMES)."""

    f_max: dict = _per_muscle(F_MAX_N)                  # N per fibre at a = 1
    force_scale: dict = _per_muscle(1.0)                # user scale of the active force
    sigma_max: float = SIGMA_MAX_MPA                    # MPa
    eps_contraction: float = EPS_CONTRACTION
    stiffening_max: float = E_CONTRACTED_KPA / E_RELAXED_KPA
    stiffening_radius: dict = field(default_factory=lambda: dict(STIFFENING_RADIUS_MM))

    def __post_init__(self):
        for name in ("f_max", "force_scale", "stiffening_radius"):
            d = getattr(self, name)
            unknown = set(d) - set(MUSCLE_NAMES)
            if unknown:
                raise ParameterError(f"{name}: unknown muscle(s) {sorted(unknown)}; "
                                     f"known: {list(MUSCLE_NAMES)}")
            for m, v in d.items():
                if not (isinstance(v, (int, float)) and v >= 0 and v == v and v != float("inf")):
                    raise ParameterError(f"{name}[{m}] = {v!r} must be a finite number >= 0")
        for name in ("sigma_max", "eps_contraction"):
            v = getattr(self, name)
            if not v > 0:
                raise ParameterError(f"{name} = {v!r} must be > 0")
        if not self.stiffening_max >= 1.0:
            raise ParameterError(f"stiffening_max = {self.stiffening_max!r} must be >= 1")

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
