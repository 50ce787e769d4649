"""Material laws as parameter sets for the numba kernels.

The ANSYS 5-parameter Mooney-Rivlin law (isochoric invariants, uncoupled volumetric part)

    W = c10 (I1b-3) + c01 (I2b-3) + c20 (I1b-3)^2 + c11 (I1b-3)(I2b-3) + c02 (I2b-3)^2
        + (J-1)^2 / d

is evaluated by solver.core.kernels.mooney_rivlin (derivatives in I1b, I2b, J) and
solver.core.kernels.invariants (the isochoric/volumetric split, written once). Defaults are
the face model's (Nazari et al.): c10 = 2.5e-3 MPa, c20 = 1.175e-3 MPa, d = 0.8 1/MPa,
so mu = 2 (c10 + c01) = 5 kPa, K = 2/d = 2.5 MPa, K/mu = 500, nu = 0.499.
"""

import math
from dataclasses import dataclass

import numpy as np

from solver.core.errors import ParameterError


@dataclass(frozen=True)
class MooneyRivlin:
    """ANSYS 5-parameter Mooney-Rivlin; moduli in MPa, d in 1/MPa."""

    c10: float = 2.5e-3
    c01: float = 0.0
    c20: float = 1.175e-3
    c11: float = 0.0
    c02: float = 0.0
    d: float = 0.8

    def __post_init__(self):
        for k in ("c10", "c01", "c20", "c11", "c02", "d"):
            v = getattr(self, k)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ParameterError(f"MooneyRivlin.{k} = {v!r} is not a finite number")
        if self.d <= 0:
            raise ParameterError(f"MooneyRivlin.d = {self.d} must be > 0 (1/MPa)")
        if self.shear_modulus <= 0:
            raise ParameterError(f"MooneyRivlin: initial shear modulus 2 (c10 + c01) = "
                                 f"{self.shear_modulus} must be > 0")

    @property
    def params(self):
        """(6,) row for the kernels: c10, c01, c20, c11, c02, d."""
        return np.array([self.c10, self.c01, self.c20, self.c11, self.c02, self.d])

    @property
    def shear_modulus(self):
        return 2.0 * (self.c10 + self.c01)

    @property
    def bulk_modulus(self):
        return 2.0 / self.d

    @property
    def poisson_ratio(self):
        k, mu = self.bulk_modulus, self.shear_modulus
        return (3 * k - 2 * mu) / (2 * (3 * k + mu))

    @classmethod
    def from_poisson(cls, c10, nu, **kw):
        """The law with d chosen for a given initial Poisson ratio (c01 from kw, default 0)."""
        mu = 2.0 * (c10 + kw.get("c01", 0.0))
        k = 2.0 * mu * (1 + nu) / (3 * (1 - 2 * nu))
        return cls(c10=c10, d=2.0 / k, **kw)
