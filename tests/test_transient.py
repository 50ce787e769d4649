"""Backward Euler: lowest-mode frequency, energy decay, order of convergence, substeps."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla

import solver
from solver.meshgen import box
from solver.terms.inertia import lumped_masses, passive_tangent
from solver.transient import Transient
from solver.units import TISSUE_DENSITY


def _bar():
    mesh = box(8, 2, 2, (20.0, 4.0, 4.0))
    model = solver.Model(mesh)
    model.fix(mesh.node_sets["xmin"])
    return mesh, model, mesh.node_sets["xmax"]


def _lowest_frequency(mesh, model):
    sysm = model.system()
    K0 = passive_tangent(model.elasticity, sysm.ndof).tocsr()[sysm.free][:, sysm.free]
    M = sp.diags(np.repeat(lumped_masses(mesh, TISSUE_DENSITY), 3)[sysm.free])
    w2 = sla.eigsh(K0, k=1, M=M, sigma=0, which="LM")[0][0]
    return np.sqrt(w2) / (2 * np.pi)


def _released(steps_per_period):
    mesh, model, tip = _bar()
    f_lin = _lowest_frequency(mesh, model)
    model.add_force(tip, (0.0, 0.0, -1e-6))          # small: the linear regime
    assert model.solve_static().converged
    model.forces.target[:] = 0.0
    dt = 1.0 / f_lin / steps_per_period
    tr = Transient(model, alpha=0.0, beta=0.0, fixed_step=dt)
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
    f_lin, f_num, energy = _released(60)
    assert f_num == pytest.approx(f_lin, rel=0.02)
    # backward Euler dissipates: energy never rises, and falls by a visible amount
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])
    assert energy[-1] < 0.7 * energy[0]


def _step_response(dt, t_end=0.02):
    mesh, model, tip = _bar()
    model.add_force(tip, (0.0, 0.0, -2e-5))
    tr = Transient(model, fixed_step=dt, hold="step")
    tr.advance(t_end)
    return model.u[tip, 2].mean()


def test_halving_dt_shows_first_order_convergence():
    ref = _step_response(0.02 / 256)
    errs = [abs(_step_response(0.02 / n) - ref) for n in (8, 16, 32)]
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((rates > 0.8) & (rates < 1.3)), rates


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
    (a, n_small), (b, n_big) = results[1e-4], results[0.02]
    assert n_big >= 10                                  # a 20 ms step is split
    # the local error bound (tol per substep) sums to a global bound
    assert abs(a - b) <= n_big * 1e-4


def test_damping_dissipates_and_bad_parameters_are_refused():
    mesh, model, tip = _bar()
    with pytest.raises(solver.ParameterError, match="alpha"):
        Transient(model, alpha=-1.0)
    with pytest.raises(solver.ParameterError, match="step end"):
        Transient(model).advance(-1.0)
