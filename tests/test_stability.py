"""Hard cases stay stable (quick versions; the full ones run from benchmarks/stress.py).

For every case: no NaN or inf, no inverted brick, aperture >= 0, dissipated energy >= 0,
and statistics reported; a step that cannot be taken is refused with the state unchanged.
"""

import resource

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from solver.anatomy.base import MUSCLE_NAMES
from solver.simulation import Simulation


@pytest.fixture(scope="module")
def sim():
    return Simulation("default")


@pytest.fixture
def fresh(sim):
    start = sim.get_state()
    sim.integrator.dissipated = 0.0
    yield sim
    sim.set_state(start)


def _check(sim, stats):
    assert stats.converged, stats.reason
    u = sim.face.u
    assert np.all(np.isfinite(u)) and np.all(np.isfinite(sim.integrator.v))
    assert sim.face.model.elasticity.min_det_f > 0.0
    out = sim.outputs()
    assert all(np.isfinite(v) for v in out.values())
    assert out["lip_aperture"] >= 0.0
    assert sim.integrator.dissipated >= 0.0
    assert stats.substeps >= 1 and stats.newton_iterations >= 0 and stats.cutbacks >= 0


def test_all_ten_muscles_stepped_from_zero_to_one(fresh):
    fresh.set_activations({m: 1.0 for m in MUSCLE_NAMES})
    for k in range(5):
        _check(fresh, fresh.step(fresh.t + 0.01))
    assert fresh.integrator.dissipated > 0.0


def test_bang_bang_antagonists_at_20_hz(fresh):
    for k in range(4):                                  # 0.1 s: two full periods
        on = k % 2 == 0
        fresh.set_activations({"OOP": 1.0 if on else 0.0, "RIS": 0.0 if on else 1.0,
                               "ZYG": 0.0 if on else 1.0})
        _check(fresh, fresh.step(fresh.t + 0.025))


@pytest.mark.parametrize("step", [1e-4, 0.1])
def test_tiny_and_huge_communication_steps(fresh, step):
    fresh.set_activations({"OOP": 0.7, "BUC": 0.7})
    for _ in range(3 if step < 0.01 else 1):
        _check(fresh, fresh.step(fresh.t + step))


def test_many_small_steps_at_rest_do_not_drift_or_grow_memory(fresh):
    fresh.set_activations({})
    fresh.step(fresh.t + 1e-3)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for _ in range(500):
        st_ = fresh.step(fresh.t + 1e-3)
        assert st_.converged
    assert np.abs(fresh.face.u).max() < 1e-9                # at rest nothing moves
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 50_000  # kB


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.lists(st.floats(0.0, 1.0), min_size=10, max_size=10), min_size=2,
                max_size=4), st.sampled_from([0.002, 0.01, 0.03]))
def test_random_activation_sequences(sim, sequence, step):
    start = sim.get_state()
    try:
        for acts in sequence:
            sim.set_activations(dict(zip(MUSCLE_NAMES, acts)))
            _check(sim, sim.step(sim.t + step))
    finally:
        sim.set_state(start)
