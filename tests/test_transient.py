"""BDF2 and backward Euler: lowest-mode frequency, energy decay, order of convergence,
substeps, error control, history across caller steps and rollbacks."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla

import solver
from solver.core.meshgen import box
from solver.core.terms.inertia import lumped_masses, passive_tangent
from solver.core.transient import Transient
from solver.core.units import TISSUE_DENSITY


def _bar():
    mesh = box(8, 2, 2, (20.0, 4.0, 4.0))
    model = solver.Model(mesh)
    model.fix(mesh.node_sets["xmin"])
    return mesh, model, mesh.node_sets["xmax"]


def _lowest_frequency(mesh, model):
    sysm = model.system()
    K0 = sysm.pattern.matrix(sysm.assemble(np.zeros(sysm.ndof))[1])[sysm.free][:, sysm.free]
    M = sp.diags(np.repeat(lumped_masses(mesh, TISSUE_DENSITY), 3)[sysm.free])
    w2 = sla.eigsh(K0, k=1, M=M, sigma=0, which="LM")[0][0]
    return np.sqrt(w2) / (2 * np.pi)


def _released(steps_per_period, method="bdf2"):
    mesh, model, tip = _bar()
    f_lin = _lowest_frequency(mesh, model)
    model.add_force(tip, (0.0, 0.0, -1e-6))          # small: the linear regime
    assert model.solve_static().converged
    model.forces.target[:] = 0.0
    dt = 1.0 / f_lin / steps_per_period
    tr = Transient(model, alpha=0.0, beta=0.0, fixed_step=dt, method=method)
    ts, zs, energy = [], [], []
    for _ in range(int(2.2 * steps_per_period)):
        tr.advance(tr.t + dt)
        ts.append(tr.t)
        zs.append(model.u[tip, 2].mean())
        energy.append(sum(tr.energy()))
    ts, zs = np.array(ts), np.array(zs)
    i = np.flatnonzero(np.sign(zs[1:]) != np.sign(zs[:-1]))
    crossings = ts[i] + (ts[i + 1] - ts[i]) * (-zs[i]) / (zs[i + 1] - zs[i])
    return f_lin, 1.0 / (2 * np.mean(np.diff(crossings))), np.array(energy)


def test_released_block_oscillates_at_the_lowest_mode_and_loses_energy():
    f_lin, f_num, energy = _released(60, "backward_euler")
    assert f_num == pytest.approx(f_lin, rel=0.02)
    # backward Euler dissipates: energy never rises, and falls by a visible amount
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])
    assert energy[-1] < 0.7 * energy[0]
    # BDF2 dissipates too (L-stable), but over 2.2 periods at 60 steps a period it keeps
    # nearly all of the energy: its numerical damping is of order (w h)^3, not (w h)
    f2, f2_num, energy2 = _released(60, "bdf2")
    assert f2_num == pytest.approx(f2, rel=0.005)
    assert np.all(np.diff(energy2[1:]) <= 1e-12 * energy2[0])
    assert 0.9 * energy2[0] < energy2[-1] < energy2[0]


def _step_response(dt, t_end=0.02, method="backward_euler"):
    mesh, model, tip = _bar()
    model.add_force(tip, (0.0, 0.0, -2e-5))
    tr = Transient(model, fixed_step=dt, hold="step", method=method)
    tr.advance(t_end)
    return model.u[tip, 2].mean()


def test_halving_dt_shows_first_order_convergence_of_backward_euler():
    # two first-order errors of opposite signs (backward Euler's, and the damping matrix
    # built on the substep's start shape) balance at coarse steps: asymptotic from 32 on
    ref = _step_response(0.02 / 1024)
    errs = [abs(_step_response(0.02 / n) - ref) for n in (32, 64, 128)]
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((rates > 0.7) & (rates < 1.3)), rates
    assert 0.85 < rates[-1] < 1.15, rates


def test_caller_steps_are_subdivided_and_land_on_time():
    results = {}
    for step in (1e-4, 0.02):
        mesh, model, tip = _bar()
        model.add_force(tip, (0.0, 0.0, -2e-5))
        tr = Transient(model, tol=1e-4, max_substep=2e-3, hold="step")
        n = int(round(0.02 / step))
        subs = 0
        for k in range(n):
            st = tr.advance((k + 1) * step)
            assert st.converged
            subs += st.substeps
        assert tr.t == pytest.approx(0.02, abs=1e-15)
        results[step] = (model.u[tip, 2].mean(), subs)
    (a, _), (b, n_big) = results[1e-4], results[0.02]
    assert n_big >= 10                                  # a 20 ms step is split
    # the local error bound (tol per substep) sums to a global bound
    assert abs(a - b) <= n_big * 1e-4


def test_damping_dissipates_and_bad_parameters_are_refused():
    mesh, model, tip = _bar()
    with pytest.raises(solver.ParameterError, match="alpha"):
        Transient(model, alpha=-1.0)
    with pytest.raises(solver.ParameterError, match="step end"):
        Transient(model).advance(-1.0)


def _spin(x):
    """Velocity (n, 3) of a rigid rotation about the z axis through the origin."""
    return np.stack([-x[:, 1], x[:, 0], np.zeros(len(x))], axis=1)


def test_damping_matrix_is_objective_and_positive():
    """K_n on a turned configuration does not damp a rigid spin (K0 on the reference one
    does: the reason K_n replaced it), and stays positive semi-definite when sheared."""
    mesh, model, _ = _bar()
    c, s = np.cos(1.0), np.sin(1.0)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    x = mesh.nodes @ R.T
    v = _spin(x)[model.elasticity.bricks].reshape(-1, 24)
    k_n = passive_tangent(model.elasticity, x - mesh.nodes)
    k_0 = passive_tangent(model.elasticity)
    scale = np.abs(k_0).max() * np.abs(v).max()
    assert np.abs(np.einsum("mij,mj->mi", k_n, v)).max() < 1e-9 * scale
    assert np.abs(np.einsum("mij,mj->mi", k_0, v)).max() > 1e-2 * scale
    sheared = mesh.nodes.copy()
    sheared[:, 0] += 0.4 * mesh.nodes[:, 2]
    w = np.linalg.eigvalsh(passive_tangent(model.elasticity, sheared - mesh.nodes))
    assert w.min() > -1e-9 * w.max()


def test_held_activation_settles_on_the_static_equilibrium():
    """OOP + BUC held at 0.5 on the coarse face (no contact): the transient state reaches
    the static equilibrium within 0.3 s (with beta K0 it crept, 3.3 mm away after 10 s)."""
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    from solver.validation.stability import lip_outputs, scene_dict
    sc = scene_dict("held", ("OOP", "BUC"), lips=False, teeth=False)
    sim = Simulation(parse_scene(sc))
    sc["scene"]["analysis"] = "static"
    static = Simulation(parse_scene(sc), loaded_anatomy=sim.anatomy)
    acts = {"OOP": 0.5, "BUC": 0.5}
    static.set_activations(acts)
    assert static.step(1.0).converged
    sim.set_activations(acts)
    for k in range(30):
        assert sim.step(0.01 * (k + 1)).converged
    now, target = lip_outputs(sim), lip_outputs(static)
    assert abs(target["lip_protrusion"]) > 5.0             # a large motion
    assert max(abs(now[k] - target[k]) for k in now) < 0.02


def test_step_error_leaves_out_the_nodes_in_contact():
    """The local error estimate skips nodes a contact pushed on at either end of the
    substep (their velocity jumps at impact: the penalty's stiff mode), not the others;
    it is the weighted max norm |est| / (atol + rtol |u|)."""
    est = np.zeros(9)
    est[0:3], est[3:6], est[6:9] = 5.0, -1.0, 0.5      # node 0 hits, node 1 touches, 2 free
    before, after = np.array([False, True, False]), np.array([True, True, False])
    u = np.zeros(9)
    assert Transient._error(est, u, 0.1, 0.0, before, after) == pytest.approx(5.0)
    assert Transient._error(est, u, 0.1, 0.0, None, after) == pytest.approx(50.0)  # unknown
    nothing = np.zeros(3, dtype=bool)
    assert Transient._error(est, u, 0.1, 0.0, nothing, nothing) == pytest.approx(50.0)
    u[6:9] = 4.0                                        # rtol: relative to the displacement
    assert Transient._error(est, u, 0.1, 0.1, before, after) == pytest.approx(0.5 / 0.5)


@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_a_step_repeated_after_set_state_repeats_exactly_with_contact(integrator):
    """With lip and teeth contact, two steps from a saved state give the same displacement
    bit for bit, whether the state was reached by stepping or restored by set_state (the
    substep error estimate leaves out the touching nodes, found at the step's start), and
    through the FMU's serialized state (BDF2: its history goes with it)."""
    from facefmu.facefmu_slave import FaceFMU
    from solver.app.simulation import Simulation
    sim = Simulation("default", integrator=integrator)
    sim.set_activations({"OOP": 0.8, "RIS": 0.4})
    for _ in range(3):
        assert sim.step(sim.t + 0.01).converged
    start = sim.get_state()
    assert (start["h_prev"] > 0) == (integrator == "bdf2")
    from solver.core._cache import kernels_warm
    assert kernels_warm()                       # a converged step marked the cache
    saved = FaceFMU._fmu_state_from_bytes(FaceFMU._fmu_state_to_bytes({"sim": start}))
    runs = []
    for state in (start, saved["sim"]):
        for _ in range(2):
            assert sim.step(sim.t + 0.01).converged
        runs.append(sim.face.u.copy())
        sim.set_state(state)
    for _ in range(2):
        assert sim.step(sim.t + 0.01).converged
    assert np.array_equal(runs[0], runs[1]) and np.array_equal(runs[0], sim.face.u)


def test_a_refused_step_keeps_the_activations_it_started_with(monkeypatch):
    """With hold = "step" every substep runs at the new activations and the first one
    accepted commits them; when a later substep of the same call fails, the refused call
    leaves the whole state (activations included) as it was."""
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    from solver.validation.stability import scene_dict
    sim = Simulation(parse_scene(scene_dict("held", ("OOP",), "step", lips=False,
                                            teeth=False)))
    sim.set_activations({"OOP": 0.2})
    assert sim.step(0.005).converged
    before = sim.get_state()
    starts = []
    real = Transient._substep

    def second_fails(self, sysm, u_n, *args, **kwargs):
        starts.append(u_n.copy())
        u, v, est, rep = real(self, sysm, u_n, *args, **kwargs)
        if not np.array_equal(u_n, starts[0]):     # a substep after an accepted one
            rep.reason = "made to fail"
            return None, None, None, rep
        return u, v, est, rep
    monkeypatch.setattr(Transient, "_substep", second_fails)
    sim.set_activations({"OOP": 0.9})
    stats = sim.step(sim.t + 0.02)                  # several substeps
    assert not stats.converged and "made to fail" in stats.reason
    assert any(not np.array_equal(u, starts[0]) for u in starts)    # one was accepted
    after = sim.get_state()
    assert after["t"] == before["t"]
    for key in ("u", "v", "activation", "u_prev", "v_prev", "h_prev", "err_prev"):
        assert np.array_equal(after[key], before[key]), key
    monkeypatch.undo()
    sim.set_activations({"OOP": 0.9})
    assert sim.step(sim.t + 0.005).converged        # and the next step works


def _smooth_gesture(h, method, anatomy=None, span=0.04):
    """The lip outputs (aperture, protrusion, width; mm) every 5 ms of a smooth gesture
    (LLSAN, OOP and RIS along 1 - cos over span, no contact) on the coarse face, at fixed
    substeps h with caller steps of h (each sees its activations at its end), Newton
    converged tightly; and the anatomy, to reuse."""
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    from solver.validation.stability import lip_outputs, scene_dict
    from conftest import smooth_rows
    sc = scene_dict("smooth", ("LLSAN", "OOP", "RIS"), lips=False, teeth=False)
    sc["solver"].update(newton_rtol=1e-10, newton_utol=1e-9, integrator=method)
    sim = Simulation(parse_scene(sc), loaded_anatomy=anatomy)
    sim.integrator.fixed_step = h
    keys = ("lip_aperture", "lip_protrusion", "lip_width")
    rows = smooth_rows(sim, h, {"LLSAN": 0.8, "OOP": 0.4, "RIS": 0.3},
                       lambda s: [lip_outputs(s)[k] for k in keys], span)
    return rows, sim.anatomy


def test_bdf2_lip_outputs_converge_at_second_order_and_backward_euler_at_first():
    """Against a tiny-step reference (h / 4 of the smallest h over 16), the largest error
    of the lip outputs falls as h^2 with BDF2 (fitted slope >= 1.8) and as h with backward
    Euler (the same fit tells them apart)."""
    hs = np.array([0.005, 0.0025, 0.00125])
    slopes = {}
    anatomy = None
    for method in ("bdf2", "backward_euler"):
        ref, anatomy = _smooth_gesture(0.04 / 256, method, anatomy)
        assert np.ptp(ref[:, 1]) > 1.0 and np.ptp(ref[:, 2]) > 1.0     # the lips moved
        errs = [np.abs(_smooth_gesture(h, method, anatomy)[0] - ref).max() for h in hs]
        slopes[method] = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert slopes["bdf2"] >= 1.8, slopes
    assert slopes["backward_euler"] < 1.5, slopes


def test_a_predictor_on_the_prescribed_path_starts_newton_on_the_targets(monkeypatch):
    """A bar's end pushed along a steady ramp: from the second step on the predictor
    carries the prescribed DOFs onto their targets' path, so Newton starts on the targets
    (no prescribed jump left); where the ramp turns back, the predicted free DOFs do not
    fit the targets, and Newton starts at the prediction, the jump its first iteration's."""
    import solver.core.transient as transient
    starts = []
    real = transient.newton

    def recording(sysm, u0, targets, *args, **kw):
        starts.append(float(np.abs(u0[sysm.prescribed] - targets).max()))
        return real(sysm, u0, targets, *args, **kw)

    monkeypatch.setattr(transient, "newton", recording)
    mesh, model, tip = _bar()
    tr = Transient(model, fixed_step=2e-3, method="bdf2", predictor="quadratic")
    path = [0.02, 0.04, 0.06, 0.08, 0.06, 0.04]          # mm along x: out, then back
    for k, x in enumerate(path):
        model.prescribe(tip, (x, 0.0, 0.0), components=(0,))
        assert tr.advance((k + 1) * 2e-3).converged
    assert starts[0] > 0.0                             # from rest: no velocity to follow
    assert max(starts[2:4]) == 0.0                     # on the ramp: on the targets
    assert starts[4] > 0.0                             # the turn: the jump is Newton's
    assert model.u[tip, 0] == pytest.approx(0.04, abs=1e-12)


def test_a_rest_of_step_just_above_the_proposal_is_taken_in_one_substep():
    """The landing rule: what is left of a caller's step, up to 1.3 times the proposal
    and max_substep, is one substep (no sliver after a 4 ms substep of a 5 ms step); not
    right after a rejection (the retry would be stretched back to the rejected size),
    and never past max_substep."""
    _, model, _ = _bar()
    tr = Transient(model, max_substep=5e-3, method="bdf2")
    assert tr._size(4e-3, 0.0, 5e-3, None) == pytest.approx(5e-3)
    assert tr._size(3e-3, 0.0, 5e-3, None) == pytest.approx(3e-3)       # 5/3 > 1.3
    assert tr._size(4e-3, 0.0, 5e-3, None, stretch=False) == pytest.approx(4e-3)
    assert tr._size(4e-3, 0.01, 0.015, None) == pytest.approx(5e-3)
    short = Transient(model, max_substep=4e-3, method="bdf2")
    assert short._size(4e-3, 0.0, 5e-3, None) == pytest.approx(4e-3)
    fixed = Transient(model, fixed_step=4e-3, method="bdf2")
    assert fixed._size(4e-3, 0.0, 5e-3, None) == pytest.approx(4e-3)


def test_the_error_estimate_leaves_out_the_prescribed_dofs(monkeypatch):
    """A tip pulled along a zigzag (its path turns at every caller step): the estimate
    the controller measures is zero on the prescribed DOFs, which take their targets
    exactly, and the steps still land on time."""
    mesh, model, tip = _bar()
    model.prescribe(tip, (0.0, 0.0, 0.0))
    tr = Transient(model, tol=1e-3, max_substep=2e-3, method="bdf2")
    pres = model.system().prescribed
    assert len(pres) == 3 * (len(mesh.node_sets["xmin"]) + len(tip))
    seen = []
    real = Transient._error

    def spy(est, u, atol, rtol, touch, touch_new):
        seen.append(np.abs(est[pres]).max())
        return real(est, u, atol, rtol, touch, touch_new)
    monkeypatch.setattr(Transient, "_error", staticmethod(spy))
    for k in range(6):
        model.prescribe(tip, (0.0, 0.0, 0.3 if k % 2 == 0 else 0.0), components=(0, 1, 2))
        assert tr.advance((k + 1) * 5e-3).converged
    assert tr.t == pytest.approx(0.03, abs=1e-15)
    assert seen and max(seen) == 0.0
    assert np.abs(model.u[tip, 2]).max() == pytest.approx(0.0, abs=1e-12)
