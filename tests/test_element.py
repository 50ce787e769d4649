"""Brick and wedge: element force = energy gradient, tangent = force derivative (FD)."""

import numpy as np
import pytest

import solver
from solver.core.element import NODE_XI, reference_geometry
from solver.core.kernels.brick import element_response

P = solver.MooneyRivlin().params
FS = {
    "uniaxial": np.diag([1.5, 0.82, 0.82]),
    "shear": np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    "random": np.eye(3) + 0.15 * np.random.default_rng(3).standard_normal((3, 3)),
}
SHAPES = {"brick": np.arange(8), "wedge": np.array([0, 1, 2, 2, 4, 5, 6, 6])}


def _element(shape, rng):
    X = (NODE_XI + 1) / 2 * np.array([2.0, 3.0, 1.5]) + 0.1 * rng.standard_normal((8, 3))
    X = X[SHAPES[shape]]                       # a wedge repeats nodes K = L, O = P
    det, dn = reference_geometry(X, np.arange(8)[None])
    return X, dn[0], det[0]


def _fd_check(ue, dn, w, form):
    E, f, K, _ = element_response(ue, dn, w, P, form)
    h = 1e-6 * max(1.0, np.abs(ue).max())
    Kn, fn = np.zeros((24, 24)), np.zeros(24)
    for c in range(24):
        up, um = ue.ravel().copy(), ue.ravel().copy()
        up[c] += h
        um[c] -= h
        Ep, fp, _, _ = element_response(up.reshape(8, 3), dn, w, P, form, False)
        Em, fm, _, _ = element_response(um.reshape(8, 3), dn, w, P, form, False)
        Kn[:, c] = (fp - fm) / (2 * h)
        fn[c] = (Ep - Em) / (2 * h)
    return f, fn, K, Kn


@pytest.mark.parametrize("form", ["mean_dilatation", "full"])
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("case", FS)
def test_tangent_matches_finite_differences(form, shape, case, rng):
    X, dn, w = _element(shape, rng)
    ue = X @ (FS[case] - np.eye(3)).T + 0.03 * rng.standard_normal((8, 3))
    ue = ue[SHAPES[shape]] if shape == "wedge" else ue   # coincident nodes move together
    f, fn, K, Kn = _fd_check(ue, dn, w, form)
    assert np.abs(f - fn).max() <= 1e-5 * np.abs(f).max()
    assert np.abs(K - Kn).max() <= 1e-5 * np.abs(K).max()
    assert np.allclose(K, K.T, rtol=0, atol=1e-14 * np.abs(K).max())


@pytest.mark.parametrize("form", ["mean_dilatation", "full"])
def test_rigid_motion_gives_no_force(form, rng):
    X, dn, w = _element("brick", rng)
    th = 0.9
    Q = np.array([[1, 0, 0], [0, np.cos(th), -np.sin(th)], [0, np.sin(th), np.cos(th)]])
    ue = X @ (Q - np.eye(3)).T + np.array([1.0, -2.0, 0.5])
    E, f, K, jmin = element_response(ue, dn, w, P, form)
    assert abs(E) < 1e-14 and np.abs(f).max() < 1e-13   # vs 0.02 N at 1 % strain
    assert jmin == pytest.approx(1.0)


def test_inverted_state_is_flagged(rng):
    X, dn, w = _element("brick", rng)
    ue = -2.0 * X                                  # F = -I: inverted everywhere
    E, f, K, jmin = element_response(ue, dn, w, P)
    assert jmin < 0 and not np.isfinite(E)


@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_reference_geometry_reproduces_linear_fields_and_the_volume(shape, rng):
    """sum_a x_a (x) dN_a/dX = I at every Gauss point (the gradient of X is exact), any
    linear field's gradient is exact, and sum_g det J = the element's volume."""
    X, dn, det = _element(shape, rng)
    assert np.all(det > 0)
    for g in range(8):
        assert np.allclose(X.T @ dn[g], np.eye(3), atol=1e-12)
    A = rng.standard_normal((3, 3))
    for g in range(8):
        assert np.allclose((X @ A.T).T @ dn[g], A, atol=1e-12)
    box = (NODE_XI + 1) / 2 * np.array([2.0, 3.0, 1.5])          # 2 x 3 x 1.5 mm
    det0, _ = reference_geometry(box, np.arange(8)[None])
    assert abs(det0.sum() - 9.0) < 1e-12


@pytest.mark.parametrize("form", ["mean_dilatation", "full"])
@pytest.mark.parametrize("shape", SHAPES)
def test_small_strain_stiffness_is_the_tangent_at_zero_strain(form, shape, rng):
    """The damping's K_n kernel (closed form in mu, kappa) against the brick kernel's
    tangent at u = 0 on the same distorted configuration, with a c20 and a c01 that the
    closed form must ignore and count (mu = 2 (c10 + c01))."""
    from solver.core.kernels.brick import FORMULATIONS
    from solver.core.kernels.mooney_rivlin import small_strain_moduli
    from solver.core.kernels.small_strain import small_strain_stiffness
    p = P.copy()
    p[1], p[2] = 0.4 * p[0], 3.0 * p[2]
    X, dn, w = _element(shape, rng)
    _, _, K, _ = element_response(np.zeros((8, 3)), dn, w, p, form)
    mu, kappa = small_strain_moduli(p)
    ke = np.empty((1, 24, 24))
    small_strain_stiffness(dn[None], w[None], np.array([mu]), np.array([kappa]),
                           FORMULATIONS[form], ke)
    assert np.abs(ke[0] - K).max() <= 1e-12 * np.abs(K).max()


@pytest.mark.parametrize("form", ["mean_dilatation", "full"])
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("case", FS)
def test_residual_and_tangent_kernels_match_the_reference_kernel(form, shape, case, rng):
    """The residual's pass (S in the invariants, solver.core.kernels.brick_residual) and the
    assembly's (node-pair contractions, solver.core.kernels.brick_tangent) against
    solver.core.kernels.brick (whose tangent the finite-difference tests above check), with
    all five Mooney-Rivlin terms switched on (c01, c11, c02 are zero in the face's law, so
    their branches are checked here only), over a block of bricks as the parallel drivers
    run them, and an inverted brick flagged."""
    from solver.core.kernels.brick import FORMULATIONS, brick_forces
    from solver.core.kernels.brick_residual import brick_residual
    from solver.core.kernels.brick_tangent import brick_tangent
    p = P.copy()
    p[1], p[3], p[4] = 0.4 * p[0], 0.3 * p[2], 0.2 * p[2]
    X, dn, w = _element(shape, rng)
    ue = X @ (FS[case] - np.eye(3)).T + 0.03 * rng.standard_normal((8, 3))
    ue = ue[SHAPES[shape]] if shape == "wedge" else ue
    m = 5                                           # bricks 0-3 deformed, 4 inverted
    u = np.concatenate([ue * s for s in (1.0, 0.5, -0.3, 1.2)] + [-2.0 * X])
    bricks = np.arange(8 * m).reshape(m, 8)
    dndX, wgp = np.repeat(dn[None], m, 0), np.repeat(w[None], m, 0)
    params = np.repeat(p[None], m, 0)
    form = FORMULATIONS[form]
    ref, res, tan = [(np.empty((m, 24)), np.empty((m, 24, 24)), np.empty(m), np.empty(m))
                     for _ in range(3)]
    brick_forces(u, bricks, dndX, wgp, params, form, True, *ref)
    brick_residual(u, bricks, dndX, wgp, params, form, res[0], res[2], res[3])
    brick_tangent(u, bricks, dndX, wgp, params, form, *tan)
    for out, parts in ((res, (0, 2)), (tan, (0, 1, 2))):
        for k in parts:
            assert np.abs(out[k][:4] - ref[k][:4]).max() <= 1e-12 * np.abs(ref[k][:4]).max()
        assert np.array_equal(out[3], ref[3]) and out[3][4] < 0 and not np.isfinite(out[2][4])
