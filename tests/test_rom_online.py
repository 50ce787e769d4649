"""The fast online step of the realtime model (solver.rom.online, .stepper, .contact,
.trust, .outputs) against the first implementation (solver.rom.reduced and the full
model's own terms), on the session's tiny trained model (conftest.py `trained`).

Every shortcut must leave the reduced solution where the reference puts it: the kernels
give the same forces and tangents, the reduced contact the same as the terms' assemble(),
the frozen-tangent Newton the same trajectory as full Newton (to its tolerance), the trust
check the same residual, the outputs the same numbers, and a rolled-back step repeats;
with the jaw (`trained_jaw`) the reduced model follows the full one while the jaw opens
and hands over outside its training envelope.
"""

import warnings

import numpy as np
import pytest

from solver.entry import open_simulation


def _rom(trained, **kw):
    """The tiny model, at Newton's tolerance 1e-4 mm (the comparisons are tighter than the
    default's 1e-2)."""
    kw.setdefault("utol", 1e-4)
    return open_simulation(trained["scene"], fidelity="realtime", rom_model=trained["path"],
                           loaded_anatomy=trained["full"].anatomy, **kw)


def _reference(trained):
    """The tiny model stepped by the reference (tests/rom_reference.py): backward Euler
    at 1 ms, full Newton, the damping matrix rebuilt every substep, no trust check."""
    from rom_reference import reference_simulation
    return reference_simulation(_rom(trained, integrator="backward_euler", trust="off"),
                                damping_refresh=1)


def _drive(sim, task, duration=None, step=1e-3, each=None):
    from solver.rom.train import drive
    return drive(sim, task["schedules"], duration or task["duration"], step, each)


def _jaw_task(trained):
    return next(t for t in trained["tasks"] if t["label"].startswith("jaw"))


@pytest.fixture(scope="module", params=["pattern", "jaw"])
def states(request):
    """(q, activations, jaw pose) along the first training pattern of `trained`, and along
    the one of `trained_jaw` that opens the jaw, reduced (the reference); and the model
    (trained or trained_jaw)."""
    jaw = request.param == "jaw"
    model = request.getfixturevalue("trained_jaw" if jaw else "trained")
    rom = _reference(model)
    out = []
    _drive(rom, _jaw_task(model) if jaw else model["tasks"][0], each=lambda s: out.append(
        (s.q.copy(), s.face.activation.start.copy(), np.array(s.jaw))))
    if jaw:
        assert max(p[0] for _, _, p in out) >= 5.0          # the jaw opens
    return rom, out, model


def _at(sim, pose, pose_n=None):
    """Put sim's jaw (the full model's terms) and its reduced operator at pose."""
    sim.face.set_jaw_state(pose)
    sim.op.set_pose(pose if pose_n is None else pose_n, pose)
    if sim.stepper.online is not None:
        sim.stepper.online.set_pose()


def test_fast_kernels_give_the_reference_operators_forces_and_tangents(states):
    rom, seq, model = states
    op = rom.op
    fsim = _rom(model, trust="off")
    fast = fsim.stepper.online
    checked = 0
    for q, a, pose in seq[len(seq) // 4::3]:
        _at(rom, pose)
        _at(fsim, pose)
        d = op.d0 + op.D @ q                 # no cable within rounding of slack
        strain = np.linalg.norm(d, axis=1) / op.L0 - 1.0 + a[op.cab_muscle] * op.cab_unit
        if np.abs(strain).min() < 1e-9:
            continue
        checked += 1
        fast.set_activation(a)
        fast.prepare_damping(q, 0.0)
        f, jmin = fast.forces(q)
        f = f.copy()                                       # a work array
        f_ref, _, j_ref = op.forces(q, a, False)
        assert jmin == pytest.approx(j_ref, rel=1e-12)
        assert np.abs(f - f_ref).max() <= 1e-9 * max(np.abs(f_ref).max(), 1e-6)
        assert fast.brick_tangent(q)
        K_ref = op.bricks_part(q, a, True)[1]
        assert np.abs(fast.stiffened_tangent() - K_ref).max() <= 1e-9 * np.abs(K_ref).max()
        if checked == 1:
            # the reference tangent itself (its projection is the fast one's): central
            # differences of the reference force, which projects by its own loop
            h = 1e-6 * max(1.0, np.abs(q).max())
            K_fd = np.column_stack([(op.bricks_part(q + h * e, a, False)[0]
                                     - op.bricks_part(q - h * e, a, False)[0]) / (2 * h)
                                    for e in np.eye(op.r)])
            assert np.abs(K_fd - K_ref).max() <= 1e-5 * np.abs(K_ref).max()
        # the cables' (the contact's: next test, against the terms themselves; the first
        # implementation left out slaves touching with zero force)
        K_ref = op.cables_part(q, a, True)[1]
        K_c = fast.switching_tangent(q, 0)
        assert np.abs(K_c - K_ref).max() <= 1e-9 * max(np.abs(K_ref).max(), 1e-6)
        # the damping: matrix-free force and matrix on the shape at q_n
        q_n = 0.9 * q
        fast.prepare_damping(q_n, 30.0)
        Kn = op.passive_stiffness(q_n)
        assert np.abs(fast.damping_tangent() - Kn).max() <= 1e-9 * np.abs(Kn).max()
        f_damped = fast.forces(q)[0].copy()
        df = 30.0 * Kn @ (q - q_n)
        assert np.abs(f_damped - f - df).max() <= 1e-9 * max(np.abs(df).max(), 1e-6)
        # a moving jaw: the lifting's velocity damped as well, K_n on the start's shape
        if pose[0] > 0.0:
            pose_n = 0.8 * pose
            _at(rom, pose, pose_n)
            _at(fsim, pose, pose_n)
            fast.prepare_damping(q_n, 0.0)
            f = fast.forces(q)[0].copy()
            fast.prepare_damping(q_n, 30.0)
            f_damped = fast.forces(q)[0].copy()
            Kn, kdl = op.passive_stiffness(q_n, op.le - op.le_n)
            assert np.abs(kdl).max() > 0.0
            df = 30.0 * (Kn @ (q - q_n) + kdl)
            assert np.abs(f_damped - f - df).max() <= 1e-9 * max(np.abs(df).max(), 1e-6)
    assert checked >= 3


def test_reduced_contact_gives_the_terms_forces_along_a_gesture(states):
    from solver.rom.contact import ReducedContact
    rom, seq, _ = states
    V, n = rom.op.V, rom.anatomy.mesh.n_nodes
    fast = ReducedContact(rom.op.contact, V, n)
    generic = ReducedContact(rom.op.contact, V, n, generic=True)
    assert fast.fast and not generic.fast
    worst = 0.0
    for q, _, pose in seq:
        rom.face.set_jaw_state(pose)                       # the generic path's terms
        L = rom.op.lifting.at(pose)[0]
        fast.set_pose(pose, L)
        generic.set_pose(pose, L)
        for need_k in (False, True):
            f1, K1 = (x.copy() if x is not None else None for x in fast.evaluate(q, need_k))
            f2, K2 = generic.evaluate(q, need_k)
            scale = max(np.abs(f2).max(), 1e-9)
            assert np.abs(f1 - f2).max() <= 1e-9 * scale
            if need_k:
                assert np.abs(K1 - K2).max() <= 1e-9 * max(np.abs(K2).max(), 1e-9)
            worst = max(worst, scale)
            assert fast.total_force == pytest.approx(generic.total_force, rel=1e-9, abs=1e-12)
    assert worst > 1e-3                                    # the gesture touches


@pytest.mark.parametrize("which", ["trained", "trained_jaw"])
def test_fast_method_follows_the_reference_method(request, which):
    trained = request.getfixturevalue(which)
    task = trained["tasks"][0] if which == "trained" else _jaw_task(trained)
    ref = _reference(trained)
    fast = _rom(trained, integrator="backward_euler", trust="off")
    a, b = _drive(ref, task), _drive(fast, task)
    for key in ("lip_aperture", "lip_protrusion"):
        assert max(abs(x[key] - y[key]) for x, y in zip(a, b)) < 5e-4, key
    assert np.abs(ref.u - fast.u).max() < 5e-4
    assert fast.last.converged and fast.mode == "rom"


def test_trust_check_gives_the_full_models_residual(states):
    from solver.core.terms.inertia import passive_tangent
    rom, seq, model = states
    chk = _rom(model).checker
    q, _, pose = seq[-1]
    rom.face.set_jaw_state(pose)                           # the cables', the teeth's pose
    L = rom.op.lifting.at(pose)[0].ravel()
    u, un = rom.op.V @ q + L, rom.op.V @ (0.8 * q) + L
    chk.sysm_all.lam = 1.0
    f_ref = chk.sysm_all.residual(u)
    assert np.abs(chk.internal_forces(u) - f_ref).max() <= 1e-10 * np.abs(f_ref).max()
    el = rom.face.model.elasticity
    ke = passive_tangent(el, un.reshape(-1, 3))
    dofs = (3 * el.bricks[:, :, None] + np.arange(3)).reshape(len(el.bricks), 24)
    du = u - un
    kdu = np.bincount(dofs.ravel(), np.einsum("eij,ej->ei", ke, du[dofs]).ravel(),
                      minlength=len(u))
    assert np.abs(chk.passive_apply(un, du) - kdu).max() <= 1e-10 * np.abs(kdu).max()


def test_lip_outputs_of_the_reduced_state_are_the_face_models(states):
    rom, seq, _ = states
    for q, _, pose in seq[::5]:
        L = rom.op.lifting.at(pose)[0]
        a = rom._outputs(q, L)
        b = rom.face.lip_outputs(rom.op.displacement(q, L))
        assert a.keys() == b.keys()
        assert all(a[k] == pytest.approx(b[k], abs=1e-12) for k in b)


def test_a_rolled_back_step_repeats_exactly(trained):
    rom = _rom(trained)
    rom.set_activations({"OOP": 0.8, "RIS": 0.4})
    for k in range(1, 4):
        rom.step(0.002 * k)
    state = rom.get_state()

    def three_steps():
        out = []
        for _ in range(3):
            assert rom.step(rom.t + 0.002).converged
            out.append(rom.outputs())
        return out
    first = three_steps()
    rom.set_state(state)
    assert three_steps() == first


def test_short_lists_distance_is_the_contact_kernels(rng):
    from solver.core.kernels.contact import nearest
    from solver.rom.contact_kernels import _triangle_d2
    xv, tris = rng.normal(size=(3, 3)), np.array([[0, 1, 2]])
    w, wt = np.empty(3), np.empty(3)
    for p in rng.normal(size=(2000, 3)) * 2:
        d2 = nearest(p, xv, tris, np.array([0]), w, wt)[2]
        assert _triangle_d2(p, xv, 0, 1, 2) == pytest.approx(d2, rel=1e-10, abs=1e-13)


def test_newton_correction_from_lu_factors_solves_the_system(rng):
    """lu_solve_small on scipy's getrf factors: -J^-1 b, with row swaps (a matrix whose
    leading entry is tiny forces them), against numpy's solver."""
    import scipy.linalg as sla
    from solver.rom.online_kernels import lu_solve_small
    for r in (1, 7, 40):
        J = rng.normal(size=(r, r)) + r * np.eye(r)
        J[0, 0] = 1e-9
        b = rng.normal(size=r)
        lu, piv = sla.lu_factor(J)
        assert r == 1 or np.any(piv != np.arange(r))
        x = np.empty(r)
        lu_solve_small(lu, piv.astype(np.int64), b, x)
        assert np.allclose(x, -np.linalg.solve(J, b), rtol=1e-10, atol=1e-12)


def test_a_rolled_back_jaw_step_repeats_exactly(trained_jaw):
    # trust off: the reduced steps themselves must repeat (the tiny model lets the lips
    # 0.07 mm into the teeth as the jaw opens, which would hand the run to the full model)
    rom = _rom(trained_jaw, trust="off")
    hi = trained_jaw["meta"]["jaw_envelope"]["jaw_opening"][1]
    assert hi >= 5.0
    rom.set_activations({"OOP": 0.5})
    rom.set_jaw(opening=0.3 * hi)
    rom.step(0.004)
    state = rom.get_state()
    assert state["jaw"][0] == 0.3 * hi

    def jaw_steps():
        out = []
        for k in range(3):
            rom.set_jaw(opening=(0.5 + 0.2 * k) * hi)
            assert rom.step(rom.t + 0.003).converged
            out.append(rom.outputs())
        return out
    first = jaw_steps()
    assert rom.mode == "rom"
    assert first[-1]["incisor_opening"] > first[0]["incisor_opening"] > 0.0
    rom.set_state(state)
    assert rom.jaw == (0.3 * hi, 0.0)
    assert jaw_steps() == first


def test_rom_follows_the_full_model_while_the_jaw_opens(trained_jaw):
    m = trained_jaw
    from solver.rom.train import drive
    rom = open_simulation(m["scene"], fidelity="realtime", rom_model=m["path"],
                          loaded_anatomy=m["full"].anatomy, trust="warn",
                          check_every=10)
    i = next(i for i, t in enumerate(m["tasks"]) if t["label"].startswith("jaw"))
    task, res = m["tasks"][i], m["results"][i]
    assert res["P"][:, 0].max() >= 5.0                     # the jaw opens by 5 deg or more
    with warnings.catch_warnings():
        warnings.simplefilter("error")                     # no trust warning on training
        rows = drive(rom, task["schedules"], task["duration"], task["interval"])
    for key in ("lip_aperture", "lip_protrusion"):
        d = max(abs(a[key] - b[key]) for a, b in zip(rows, res["rows"]))
        span = np.ptp([b[key] for b in res["rows"]])
        assert d < 0.05 + 0.01 * span, (key, d, span)
    # the jaw's pose is prescribed: the same incisor opening to rounding
    assert max(abs(a["incisor_opening"] - b["incisor_opening"])
               for a, b in zip(rows, res["rows"])) < 1e-9
    assert rows[-1]["incisor_opening"] > 5.0
    assert np.abs(rom.u.ravel() - res["U"][:, -1]).max() < 0.1 + 0.01 * np.abs(res["U"]).max()
    assert rom.mode == "rom" and rom.jaw == tuple(res["P"][-1])


def test_rom_keeps_the_tissues_volume_as_the_full_model_while_the_jaw_opens(trained_jaw):
    """Volume measured outside both models: each brick's volume from the displacements
    (Gauss weights det J of X + u, solver.core.element.reference_geometry) along the run
    that opens the jaw. The tissue's volume changes as the full model's does (K / mu =
    500: not zero) and no brick's volume departs from the full state's by more than the
    largest change of a brick in the full run. (A reduced model whose volume
    constraint is relaxed fails this: its tissue loses twice the full model's volume.)"""
    from solver.core.element import reference_geometry
    from solver.rom.train import drive
    m = trained_jaw
    rom = open_simulation(m["scene"], fidelity="realtime", rom_model=m["path"],
                          loaded_anatomy=m["full"].anatomy, trust="off")
    i = next(i for i, t in enumerate(m["tasks"]) if t["label"].startswith("jaw"))
    task, res = m["tasks"][i], m["results"][i]
    us = []
    drive(rom, task["schedules"], task["duration"], task["interval"],
          lambda s: us.append(s.u.reshape(-1, 3).copy()))
    mesh = rom.anatomy.mesh
    vol0 = mesh.volumes

    def change(u):                                     # (bricks,) v - V, mm^3
        return reference_geometry(mesh.nodes + u, mesh.bricks)[0].sum(axis=1) - vol0
    assert len(us) == res["U"].shape[1]
    total, total_full, brick, brick_full = [], [], [], []
    for k, u in enumerate(us):
        dv, dvf = change(u), change(res["U"][:, k].reshape(-1, 3))
        total.append(abs(dv.sum()))
        total_full.append(abs(dvf.sum()))
        brick.append(np.abs(dv - dvf).max())
        brick_full.append(np.abs(dvf).max())
    assert 0.0 < max(total_full) < 1e-3 * vol0.sum()
    assert max(total) <= 1.25 * max(total_full), (max(total), max(total_full))
    assert max(brick) <= max(brick_full), (max(brick), max(brick_full))


def test_a_jaw_pose_outside_the_training_envelope_falls_back_with_a_warning(trained_jaw):
    m = trained_jaw
    from solver.face.jaw import JAW_INPUTS, JAW_RANGES
    from solver.rom.simulation import TrustWarning
    rom = open_simulation(m["scene"], fidelity="realtime", rom_model=m["path"],
                          loaded_anatomy=m["full"].anatomy)
    env = m["meta"]["jaw_envelope"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")                     # inside: no warning
        rom.set_jaw(opening=0.5 * sum(env["jaw_opening"]))
    assert rom.mode == "rom"
    name, value = next((n, JAW_RANGES[n][1]) for n in JAW_INPUTS
                       if env[n][1] < JAW_RANGES[n][1])
    with pytest.warns(TrustWarning, match=f"{name} = {value:g} .* outside its training"):
        rom.set_jaw(**{name[4:]: value})
    assert rom.mode == "full"
    assert rom.step(0.002).converged and rom.jaw[JAW_INPUTS.index(name)] == value


def _rom_smooth(trained, h, integrator, span=0.04):
    """The ROM's lip outputs (aperture, protrusion; mm) every 5 ms of a smooth gesture (the
    tiny model's three muscles along 1 - cos over span) at fixed substeps h with caller
    steps of h, Newton converged tightly."""
    from conftest import smooth_rows
    rom = _rom(trained, integrator=integrator, tol=None, h=h, utol=1e-9, trust="off")
    return smooth_rows(rom, h, {"OOP": 0.5, "RIS": 0.4, "DLI": 0.4},
                       lambda s: [s.outputs()[k] for k in ("lip_aperture", "lip_protrusion")],
                       span)


def test_reduced_bdf2_converges_at_second_order_and_backward_euler_at_first(trained_smooth):
    """The reduced model's own time error, against its tiny-step run (a model without
    contact, whose penalty's kinks would cap the order): the largest error of the lip
    outputs falls as h^2 with BDF2 (fitted slope >= 1.8) and as h with backward Euler
    (slope < 1.5)."""
    trained = trained_smooth
    hs = np.array([0.005, 0.0025, 0.00125])
    slopes = {}
    for integrator in ("bdf2", "backward_euler"):
        ref = _rom_smooth(trained, 0.00125 / 8, integrator)
        assert np.ptp(ref[:, 0]) > 0.3 or np.ptp(ref[:, 1]) > 0.3      # the lips moved
        errs = [np.abs(_rom_smooth(trained, h, integrator) - ref).max() for h in hs]
        slopes[integrator] = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert slopes["bdf2"] >= 1.8, slopes
    assert slopes["backward_euler"] < 1.5, slopes
