"""Mooney-Rivlin law: zero stress at identity, stress and tangent against finite differences."""

import numpy as np
import pytest

import solver
from solver.core.kernels.material_point import response

PARAMS = [solver.MooneyRivlin().params,
          solver.MooneyRivlin(c10=2e-3, c01=1e-3, c20=1e-3, c11=5e-4, c02=3e-4, d=0.1).params]
CASES = {
    "uniaxial": np.diag([1.3, 0.88, 0.88]),
    "shear": np.array([[1.0, 0.4, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    "random": np.eye(3) + 0.2 * np.random.default_rng(7).standard_normal((3, 3)),
}


@pytest.mark.parametrize("p", PARAMS)
def test_zero_stress_and_energy_at_identity(p):
    W, P, S, D = response(np.eye(3), p)
    assert W == 0.0
    assert np.abs(P).max() < 1e-15


@pytest.mark.parametrize("p", PARAMS)
@pytest.mark.parametrize("case", CASES)
def test_first_piola_is_energy_derivative(p, case):
    F = CASES[case]
    _, P, _, _ = response(F, p)
    h = 1e-6
    Pn = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            dF = np.zeros((3, 3))
            dF[i, j] = h
            Pn[i, j] = (response(F + dF, p)[0] - response(F - dF, p)[0]) / (2 * h)
    assert np.abs(P - Pn).max() <= 1e-6 * np.abs(P).max()


@pytest.mark.parametrize("p", PARAMS)
@pytest.mark.parametrize("case", CASES)
def test_material_tangent_is_stress_derivative(p, case):
    """D_IJKL = 2 dS_IJ / dC_KL, checked in Voigt form against central differences."""
    from solver.core.kernels.invariants import VOIGT
    from solver.core.kernels.material_point import point_response
    F = CASES[case]
    C = F.T @ F
    S, D = np.empty((3, 3)), np.empty((6, 6))
    point_response(C, p, True, True, S, D)
    h = 1e-7
    Dn = np.zeros((6, 6))
    for q, (k, l) in enumerate(VOIGT):
        dC = np.zeros((3, 3))
        dC[k, l] += h
        dC[l, k] += h if k != l else 0.0
        Sp, Sm, Dd = np.empty((3, 3)), np.empty((3, 3)), np.empty((6, 6))
        point_response(C + dC, p, True, True, Sp, Dd)
        point_response(C - dC, p, True, True, Sm, Dd)
        dS = (Sp - Sm) / (2 * h)
        scale = 1.0 if k == l else 0.5            # a shear entry of C moves two components
        for r, (i, j) in enumerate(VOIGT):
            Dn[r, q] = 2.0 * dS[i, j] * scale
    assert np.abs(D - Dn).max() <= 1e-5 * np.abs(D).max()


def test_objectivity_rotation_gives_rotated_stress():
    p = PARAMS[1]
    F = CASES["random"]
    th = 0.7
    Q = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    W1, P1, S1, _ = response(F, p)
    W2, P2, S2, _ = response(Q @ F, p)
    assert abs(W1 - W2) < 1e-14
    assert np.allclose(S1, S2, atol=1e-14) and np.allclose(Q @ P1, P2, atol=1e-14)


def test_paper_defaults_are_nearly_incompressible():
    m = solver.MooneyRivlin()
    assert (m.c10, m.c20, m.d) == (2.5e-3, 1.175e-3, 0.8)
    assert m.bulk_modulus / m.shear_modulus == pytest.approx(500.0)
    assert m.poisson_ratio == pytest.approx(0.499, abs=1e-4)


@pytest.mark.parametrize("kw,name", [({"d": 0.0}, "d"), ({"c10": float("nan")}, "c10"),
                                      ({"c10": -1e-3}, "shear modulus")])
def test_impossible_parameters_are_refused_by_name(kw, name):
    with pytest.raises(solver.ParameterError, match=name):
        solver.MooneyRivlin(**kw)
