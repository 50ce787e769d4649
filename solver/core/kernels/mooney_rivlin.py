r"""The ANSYS 5-parameter Mooney-Rivlin law as derivatives in (I1b, I2b, J).

    W = c10 (I1b-3) + c01 (I2b-3) + c20 (I1b-3)^2 + c11 (I1b-3)(I2b-3) + c02 (I2b-3)^2
        + (J-1)^2 / d

params row p: (c10, c01, c20, c11, c02, d) in MPa, MPa, MPa, MPa, MPa, 1/MPa.
"""

import numpy as np
from numba import njit


@njit(cache=True)
def iso_energy(I1b, I2b, p, wb, wbb):
    """Isochoric energy; fills wb[0:2], wbb[0:2, 0:2] with derivatives in (I1b, I2b)."""
    a = I1b - 3.0
    b = I2b - 3.0
    c10, c01, c20, c11, c02 = p[0], p[1], p[2], p[3], p[4]
    wb[0] = c10 + 2.0 * c20 * a + c11 * b
    wb[1] = c01 + c11 * a + 2.0 * c02 * b
    wbb[0, 0] = 2.0 * c20
    wbb[0, 1] = c11
    wbb[1, 0] = c11
    wbb[1, 1] = 2.0 * c02
    return c10 * a + c01 * b + c20 * a * a + c11 * a * b + c02 * b * b


@njit(cache=True)
def vol_energy(J, p):
    """U(J) = (J-1)^2/d and its first two derivatives; returns (U, U', U'')."""
    d = p[5]
    return (J - 1.0) ** 2 / d, 2.0 * (J - 1.0) / d, 2.0 / d


def small_strain_moduli(p):
    """Initial shear and bulk moduli (MPa) of a params row: mu = 2 (c10 + c01), K = 2/d."""
    p = np.asarray(p, dtype=float)
    return 2.0 * (p[0] + p[1]), 2.0 / p[5]
