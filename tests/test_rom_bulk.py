"""The reduced bulk term (solver.rom.bulk) on the session's tiny jaw model (conftest.py
`trained_jaw`: coarse half face, a muscle pattern and a run that opens the jaw).

The term must be the full model's volumetric energy when it keeps every brick, its
forces and tangents the derivatives of its energy, the fast online step must give the
reference operator's numbers with it, and a model with it must follow the full model and
keep the tissue's volume as the full model does.
"""

import numpy as np
import pytest


def _jaw_states(model, every=2):
    """(q, activations, pose) along the run of `model` that opens the jaw."""
    V = model["arrays"]["V"]
    i = next(i for i, t in enumerate(model["tasks"]) if t["label"].startswith("jaw"))
    res = model["results"][i]
    cols = range(2, res["U"].shape[1], every)
    return [(V.T @ res["U"][:, j], res["A"][j], res["P"][j]) for j in cols]


def _every_brick(full, V, bulk):
    from solver.rom.reduced import ReducedOperator
    n, r = full.anatomy.mesh.n_bricks, V.shape[1]
    return ReducedOperator(full, V, np.arange(n), np.ones(n), np.zeros((r, r)),
                           np.zeros((r, r)), bulk)


def _rom(model, bulk_model, **kw):
    from solver.entry import open_simulation
    arrays, meta, _ = bulk_model
    return open_simulation(model["scene"], fidelity="realtime", rom_model=(arrays, meta),
                           loaded_anatomy=model["full"].anatomy, trust="off", **kw)


def _rel(a, b):
    return np.abs(a - b).max() / max(np.abs(b).max(), 1e-12)


def test_with_every_brick_the_reduced_bulk_term_is_the_full_models_volumetric_energy(
        trained_jaw):
    from solver.rom.train import reduced_matrices
    full, V = trained_jaw["full"], trained_jaw["arrays"]["V"]
    n = full.anatomy.mesh.n_bricks
    ident = (np.arange(n), np.eye(n))
    pen, red = _every_brick(full, V, None), _every_brick(full, V, ident)
    assert np.all(np.isinf(red.params[:, 5])) and np.all(np.isfinite(pen.params[:, 5]))
    checked = 0
    for q, a, pose in _jaw_states(trained_jaw, 2):
        for op in (pen, red):
            op.set_pose(0.8 * pose, pose)
        f0, K0, j0 = pen.bricks_part(q, a, True)
        f1, K1, j1 = red.bricks_part(q, a, True)
        assert j1 == j0 and _rel(f1, f0) < 1e-9 and _rel(K1, K0) < 1e-9
        # the damping: K_n on the shape at q, and the jaw's velocity through it
        assert _rel(red.passive_stiffness(q), pen.passive_stiffness(q)) < 1e-9
        if pose[0] > 0:
            ld0 = pen.lifting_damping(q)
            assert np.abs(ld0).max() > 0 and _rel(red.lifting_damping(q), ld0) < 1e-9
            checked += 1
    assert checked >= 2
    K0_pen = reduced_matrices(full, V)[1]
    assert _rel(reduced_matrices(full, V, ident)[1], K0_pen) < 1e-9


@pytest.fixture(scope="module")
def bulk_model(trained_jaw):
    """trained_jaw's basis with a reduced bulk term of 20 modes (as many as its
    snapshots: fewer leave some of the 14 displacement modes' volume change free, and
    the tissue then loses twice the full model's volume) on 24 sampled bricks
    (solver.rom.train's helpers on its snapshots), its cubature re-fitted to the
    isochoric forces: (arrays, meta, sigma)."""
    from solver.rom.train import cubature, reduced_bulk, reduced_matrices
    full, a = trained_jaw["full"], dict(trained_jaw["arrays"])
    U = np.hstack([r["U"] for r in trained_jaw["results"]])
    A = np.vstack([r["A"] for r in trained_jaw["results"]])
    I, Ab, sigma = reduced_bulk(full, U, 20, 4)
    bricks, weights, _ = cubature(full, a["V"], U, A, 1e-2, 150, iso=True)
    M_r, K0_r = reduced_matrices(full, a["V"], (I, Ab))
    a.update(bricks=bricks, weights=weights, M_r=M_r, K0_r=K0_r, bulk_bricks=I, bulk_A=Ab)
    return a, dict(trained_jaw["meta"], bulk_modes=20), sigma


def test_dilatation_modes_are_recovered_from_the_sampled_bricks(trained_jaw, bulk_model):
    from solver.rom.bulk import bulk_modes, sample_bricks
    from solver.rom.train import bulk_snapshots
    U = np.hstack([r["U"] for r in trained_jaw["results"]])
    S = bulk_snapshots(trained_jaw["full"], U)
    assert np.abs(S).max() > 0
    P, sigma = bulk_modes(S, 6)
    assert np.allclose(P.T @ P, np.eye(6), atol=1e-12)
    I, A = sample_bricks(P, 3)
    assert len(np.unique(I)) == 9
    assert np.allclose(A @ P[I], np.eye(6), atol=1e-9)      # c = A s_I is P^T s on span P
    s = P @ np.arange(1.0, 7.0)
    assert np.allclose(A @ s[I], P.T @ s, atol=1e-9)
    # the dilatations are the full model's volume changes: brick volumes by the divergence
    # theorem would be another code path; the rest state is 0, a uniform stretch exact
    mesh = trained_jaw["full"].anatomy.mesh
    u = 0.01 * mesh.nodes
    S2 = bulk_snapshots(trained_jaw["full"], np.stack([0 * u.ravel(), u.ravel()], axis=1))
    from solver.rom.bulk import bulk_scale
    ce = bulk_scale(trained_jaw["full"].face.model.elasticity.params, mesh.det_j)
    assert np.abs(S2[:, 0]).max() == 0.0
    assert np.allclose(S2[:, 1] / ce, (1.01 ** 3 - 1) * mesh.det_j.sum(axis=1), rtol=1e-10)


def test_bulk_forces_and_tangent_are_derivatives_of_its_energy(trained_jaw, bulk_model):
    from solver.rom.bulk import ReducedBulk
    arrays = bulk_model[0]
    full, V = trained_jaw["full"], arrays["V"]
    mesh = full.anatomy.mesh
    rb = ReducedBulk(mesh, full.face.model.elasticity.params,
                     V.reshape(mesh.n_nodes, 3, -1), arrays["bulk_bricks"], arrays["bulk_A"])
    q, _, pose = _jaw_states(trained_jaw)[-1]
    L = np.zeros((mesh.n_nodes, 3))
    L[full.face.jaw.geometry.nodes] = full.face.jaw.displacement(pose)
    le = rb.lifting(L)
    f, K = rb.forces(q, le, True)
    assert np.abs(f).max() > 0
    h = 1e-5 * max(1.0, np.abs(q).max())
    E = np.eye(len(q))
    f_fd = np.array([(rb.energy(q + h * e, le) - rb.energy(q - h * e, le)) / (2 * h)
                     for e in E])
    assert _rel(f_fd, f) < 1e-6
    K_fd = np.column_stack([(rb.forces(q + h * e, le, False)[0]
                             - rb.forces(q - h * e, le, False)[0]) / (2 * h) for e in E])
    assert _rel(K_fd, K) < 1e-6
    # at rest, the damping's J_n is the tangent's J: J^T J is K's Gauss-Newton part
    J0 = rb.jacobian(np.zeros_like(q), 0 * le)
    assert _rel(J0.T @ J0, rb.forces(np.zeros_like(q), 0 * le, True)[1]) < 1e-12


def test_fast_online_step_gives_the_reference_operator_with_a_bulk_term(trained_jaw,
                                                                       bulk_model):
    rom = _rom(trained_jaw, bulk_model)
    op, fast = rom.op, rom.stepper.online
    assert op.bulk is not None
    moving = 0
    for q, act, pose in _jaw_states(trained_jaw, 2):
        rom.face.set_jaw_state(pose)
        op.set_pose(pose, pose)
        fast.set_pose()
        fast.set_activation(act)
        fast.prepare_damping(q, 0.0)
        f = fast.forces(q)[0].copy()
        f_ref = op.forces(q, act, False)[0]
        assert _rel(f, f_ref) < 1e-9
        assert fast.brick_tangent(q)
        assert _rel(fast.stiffened_tangent(), op.bricks_part(q, act, True)[1]) < 1e-9
        q_n = 0.9 * q
        fast.prepare_damping(q_n, 30.0)
        Kn = op.passive_stiffness(q_n)
        assert _rel(fast.damping_tangent(), Kn) < 1e-9
        df = 30.0 * Kn @ (q - q_n)
        assert _rel(fast.forces(q)[0] - f, df) < 1e-9
        if pose[0] > 0.0:                  # the jaw moving: its velocity damped as well
            op.set_pose(0.8 * pose, pose)
            fast.set_pose()
            fast.prepare_damping(q_n, 0.0)
            f = fast.forces(q)[0].copy()
            fast.prepare_damping(q_n, 30.0)
            df = 30.0 * (op.passive_stiffness(q_n) @ (q - q_n) + op.lifting_damping(q_n))
            assert _rel(fast.forces(q)[0] - f, df) < 1e-9
            moving += 1
    assert moving >= 2


def test_a_model_with_a_bulk_term_follows_the_full_model_and_keeps_its_volume(
        trained_jaw, bulk_model):
    """The jaw run (training data) at 1 ms steps: lip outputs as the full model's, and
    the tissue's volume change, measured brick by brick outside the model
    (solver.rom.bulk.dilatations on the reconstructed displacements), within the full
    model's own."""
    from solver.rom.bulk import dilatations
    from solver.rom.train import drive
    i = next(i for i, t in enumerate(trained_jaw["tasks"]) if t["label"].startswith("jaw"))
    task, res = trained_jaw["tasks"][i], trained_jaw["results"][i]
    rom = _rom(trained_jaw, bulk_model)
    assert rom.op.bulk is not None
    mesh = rom.anatomy.mesh
    us = []
    rows = drive(rom, task["schedules"], task["duration"], task["interval"],
                 lambda s: us.append(s.u.copy()))
    dv, dvf = np.empty(mesh.n_bricks), np.empty(mesh.n_bricks)
    vol = mesh.det_j.sum(axis=1)
    for key in ("lip_aperture", "lip_protrusion"):        # as the penalty's model
        d = max(abs(a[key] - b[key]) for a, b in zip(rows, res["rows"]))
        span = np.ptp([b[key] for b in res["rows"]])
        assert d < 0.05 + 0.01 * span, (key, d, span)
    total, total_full, brick, brick_full = [], [], [], []
    for k, u in enumerate(us):
        assert dilatations(u.reshape(-1, 3), mesh.bricks, mesh.dn_dx, mesh.det_j, dv) == 0
        dilatations(res["U"][:, k].reshape(-1, 3), mesh.bricks, mesh.dn_dx, mesh.det_j, dvf)
        total.append(abs(dv.sum()))
        total_full.append(abs(dvf.sum()))
        brick.append(np.abs(dv - dvf).max())
        brick_full.append(np.abs(dvf).max())
    # mm^3: the tissue's volume change as the full model's (which is not 0: K / mu =
    # 500), and brick by brick within the largest change of a brick in the full run
    assert 0 < max(total_full) < 1e-3 * vol.sum()
    assert max(total) <= 1.25 * max(total_full), (max(total), max(total_full))
    assert max(brick) <= max(brick_full), (max(brick), max(brick_full))


def test_training_with_a_bulk_term_saves_and_loads_it(trained_jaw, bulk_model, tmp_path):
    """solver.rom.train.train(bulk_modes=...) on the same tiny runs: the file holds the
    term (the same sampled bricks as the helpers give), and a simulation opened from it
    uses it."""
    from solver.entry import open_simulation
    from solver.rom.store import load_model
    from solver.rom.train import train
    path = train(trained_jaw["scene"], sim=trained_jaw["full"], runs=1, duration=0.05,
                 interval=0.005, seed=3, calibration_runs=1, out=tmp_path / "bulk.npz",
                 progress=False, sim_only=True, jaw_runs=1, bulk_modes=20, bulk_extra=4)
    arrays, meta = load_model(path)
    assert meta["bulk_modes"] == 20 and meta["bulk_samples"] == 24
    assert np.array_equal(arrays["bulk_bricks"], bulk_model[0]["bulk_bricks"])
    assert np.allclose(arrays["bulk_A"], bulk_model[0]["bulk_A"])
    assert np.array_equal(arrays["bricks"], bulk_model[0]["bricks"])
    rom = open_simulation(trained_jaw["scene"], fidelity="realtime", rom_model=path,
                          loaded_anatomy=trained_jaw["full"].anatomy)
    assert rom.op.bulk is not None and np.all(np.isinf(rom.op.params[:, 5]))
    plain = open_simulation(trained_jaw["scene"], fidelity="realtime",
                            rom_model=trained_jaw["path"],
                            loaded_anatomy=trained_jaw["full"].anatomy)
    assert plain.op.bulk is None and np.all(np.isfinite(plain.op.params[:, 5]))
