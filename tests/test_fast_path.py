"""The fast full-order path (issue 10): factorization reuse, warm starts, BLAS threads."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import solver
from solver.core.linsolve import SuperLU, available, make_solver, single_threaded_blas
from solver.core.meshgen import box
from solver.core.newton import NewtonOptions, newton
from solver.core.transient import Transient
from conftest import REFERENCE_BALANCED, assert_same_lips, gesture_both_ways

TIP_FORCE = (0.0, 0.0, -1e-4)       # N: about 1.3 mm of tip deflection, a nonlinear bend


def _bar():
    mesh = box(8, 2, 2, (20.0, 4.0, 4.0))
    model = solver.Model(mesh)
    model.fix(mesh.node_sets["xmin"])
    model.add_force(mesh.node_sets["xmax"], TIP_FORCE)
    return model


def _run(reuse=True, t_end=0.02, **transient):
    """The bar released under a tip force: (u at t_end, StepStats, model)."""
    model = _bar()
    model.newton_options.reuse = reuse
    tr = Transient(model, hold="step", **transient)
    stats = tr.advance(t_end)
    assert stats.converged
    return model.u.copy(), stats, model


def test_reuse_gives_full_newtons_solution_with_fewer_factorizations():
    u_full, s_full, _ = _run(reuse=False)
    u_mod, s_mod, m_mod = _run(reuse=True)
    assert np.abs(u_full).max() > 1.0                          # a large motion
    assert np.abs(u_mod - u_full).max() < 1e-4                  # mm: Newton tolerance
    assert s_mod.substeps == s_full.substeps
    assert s_full.factorizations == s_full.newton_iterations    # full Newton: one per iteration
    assert s_mod.factorizations < 0.7 * s_full.factorizations
    assert m_mod.linear_solver.factorizations == s_mod.factorizations


def test_default_reuses_in_time_stepping_only():
    _, s_mod, _ = _run(reuse=True)
    _, s_default, _ = _run(reuse=None)
    assert s_default.factorizations == s_mod.factorizations
    model = _bar()
    model.forces.target[:] *= 0.1
    res = model.solve_static()
    assert res.converged and model.linear_solver.factorizations == res.iterations


def _substep_case(scale, h=2e-3):
    """Newton's problem of the bar's first substep of size h under scale x the tip force:
    (system, targets, start)."""
    model = _bar()
    model.forces.target[:] *= scale
    tr = Transient(model, hold="step")
    sysm = model.system()
    u0 = np.zeros(sysm.ndof)
    stage = tr._stage(u0, u0, h, None)[0]          # backward Euler from rest
    for term in tr.step_terms:
        term.prepare(stage)
    return sysm, np.zeros(len(sysm.prescribed)), u0


def test_slow_convergence_refactorizes_and_converges():
    """100 x the force in one substep (a 1.8 mm jump): the tangent changes along the
    iteration, the reused factorization's iterations slow down, and Newton refactorizes
    (several times) instead of crawling on it; same solution as full Newton."""
    sysm, tg, u0 = _substep_case(100.0)
    opts = NewtonOptions(reuse=True)
    u, _, rep = newton(sysm, u0, tg, make_solver("auto"), opts, key=2e-3)
    assert rep.converged and rep.factorizations >= 2
    assert rep.factorizations < rep.iterations
    res = rep.residuals
    assert any(res[k] > opts.refactor_ratio * res[k - 1] for k in range(1, len(res)))
    u_full, _, rep_full = newton(sysm, u0, tg, make_solver("auto"), NewtonOptions(reuse=False))
    assert rep_full.converged and rep_full.factorizations == rep_full.iterations
    assert np.abs(u_full).max() > 1.0
    assert np.abs(u - u_full).max() < 1e-4


def test_a_reused_factorization_is_kept_while_it_converges_at_a_paying_rate():
    """20 x the force: the reused factorization converges at rates 0.2-0.3 per iteration,
    which pay against a new factorization (NewtonOptions.refactor_ratio 0.7); a ratio of
    0.1 (the former default) refactorizes there. Same solution."""
    sysm, tg, u0 = _substep_case(20.0)
    u, _, rep = newton(sysm, u0, tg, make_solver("auto"), NewtonOptions(reuse=True), key=2e-3)
    tight = NewtonOptions(reuse=True, refactor_ratio=0.1)
    u1, _, rep1 = newton(sysm, u0, tg, make_solver("auto"), tight, key=2e-3)
    assert rep.converged and rep1.converged
    assert rep.factorizations < rep1.factorizations
    assert np.abs(u - u1).max() < 1e-6


def test_reuse_refactorizes_when_its_rate_would_run_out_of_iterations():
    """50 x the force, 12 iterations allowed: the reused factorization's rate (about 0.45)
    would need about 20; Newton refactorizes in time and converges."""
    sysm, tg, u0 = _substep_case(50.0)
    opts = NewtonOptions(reuse=True, max_iter=12)
    _, _, rep = newton(sysm, u0, tg, make_solver("auto"), opts, key=2e-3)
    assert rep.converged and rep.iterations <= 12 and rep.factorizations >= 3


def test_factorization_is_reused_only_for_the_same_system_and_key():
    sysm, tg, u0 = _substep_case(1.0)
    lin = make_solver("auto")
    opts = NewtonOptions(reuse=True)
    u1, _, rep1 = newton(sysm, u0, tg, lin, opts, key=1.0)
    assert rep1.converged and rep1.factorizations >= 1
    start = u1.copy()
    start[sysm.free] += 1e-3                                        # off the solution
    u2, _, rep2 = newton(sysm, start, tg, lin, opts, key=1.0)       # same key: reused
    assert rep2.converged and rep2.factorizations == 0 and rep2.iterations >= 1
    _, _, rep3 = newton(sysm, start, tg, lin, opts, key=2.0)        # another key: new one
    assert rep3.converged and rep3.factorizations >= 1
    assert np.abs(u2 - u1).max() < 1e-4


def test_a_stale_factorizations_overshooting_step_is_dropped_for_a_new_one():
    """The factorization of the bar's equilibrium under 1 x the force, reused (same key)
    for 100 x: its full step fails the line search's test, so Newton drops it and
    factorizes at the same iterate (no search along the stale direction); same answer as
    full Newton."""
    sysm, tg, u0 = _substep_case(1.0)
    lin, opts = make_solver("auto"), NewtonOptions(reuse=True)
    u1, _, rep1 = newton(sysm, u0, tg, lin, opts, key=1.0)
    assert rep1.converged and rep1.stale_steps == 0
    sysm.term("nodal_forces").target[:] *= 100.0
    u2, _, rep2 = newton(sysm, u1, tg, lin, opts, key=1.0)
    assert rep2.converged and rep2.stale_steps >= 1 and rep2.factorizations >= 1
    u_full, _, rep_full = newton(sysm, u1, tg, make_solver("auto"), NewtonOptions(reuse=False))
    assert rep_full.converged and rep_full.stale_steps == 0
    assert np.abs(u_full - u1).max() > 1.0
    assert np.abs(u2 - u_full).max() < 1e-4


def test_a_step_shortened_to_land_does_not_shrink_the_next_caller_steps_substeps():
    """Substeps up to 2 ms, no binding error control: the caller step to 4.2 ms ends with
    a 0.2 ms remnant; the next caller step still starts with a 2 ms substep (before, twice
    the remnant: 0.4 ms, then 0.8 and 1.6)."""
    tr = Transient(_bar(), hold="step", max_substep=2e-3, tol=10.0)
    substeps = [[h for _, h, _ in tr.advance(t).history] for t in (2e-3, 4.2e-3, 8.2e-3)]
    assert substeps[1] == pytest.approx([2e-3, 2e-4])
    assert substeps[2] == pytest.approx([2e-3, 2e-3])


def test_failed_step_leaves_the_state_and_drops_the_factorization():
    model = _bar()
    tr = Transient(model, hold="step", max_cutbacks=0)
    assert tr.advance(0.002).converged
    u, v = model.u.copy(), tr.v.copy()
    model.newton_options.max_iter = 1                 # cannot converge: the step fails
    model.forces.target[:] *= 50.0
    stats = tr.advance(0.02)
    assert not stats.converged
    assert np.array_equal(model.u, u) and np.array_equal(tr.v, v) and tr.t == 0.002
    assert model.linear_solver.tag is None
    model.newton_options.max_iter = 25                # and the next valid step works
    assert tr.advance(0.004).converged


@pytest.mark.parametrize("predictor", ["none", "quadratic"])
def test_predictor_does_not_change_the_converged_answer(predictor):
    u_ref, s_ref, _ = _run(fixed_step=1e-3)
    u, s, _ = _run(fixed_step=1e-3, predictor=predictor)
    assert np.abs(u - u_ref).max() < 1e-4
    assert s.substeps == s_ref.substeps == 20


def test_even_steps_land_without_remnants_and_stay_accurate():
    u_ref, _, _ = _run(t_end=0.0203)
    model = _bar()
    tr = Transient(model, hold="step", even_steps=True)
    stats = tr.advance(0.0203)
    assert stats.converged
    hs = [h for _, h, _ in stats.history]
    assert min(hs) > 0.2 * max(hs)                    # no tiny remnant at the end
    assert np.abs(model.u - u_ref).max() < 0.05       # mm: both within the error control


@pytest.mark.parametrize("method", ["backward_euler", "bdf2"])
def test_caller_step_repeats_exactly_with_reuse(method):
    """Each caller step starts with a new factorization: a repeated step (an FMU rollback)
    gives the same bits (BDF2: with its history and its controller's last error put back)."""
    model = _bar()
    tr = Transient(model, hold="step", method=method)
    tr.advance(0.005)
    u, v, h, hist, err = model.u.copy(), tr.v.copy(), tr.h, tr.history, tr.err_prev
    assert (hist is not None) == (method == "bdf2")
    tr.advance(0.01)
    first = model.u.copy()
    model.u, tr.v, tr.h, tr.t = u.copy(), v.copy(), h, 0.005
    tr.history, tr.err_prev = hist, err
    tr.advance(0.01)
    assert np.array_equal(model.u, first)


def test_single_threaded_blas_restores_the_thread_count():
    from threadpoolctl import threadpool_info

    def openblas():
        return [i["num_threads"] for i in threadpool_info() if i["internal_api"] == "openblas"]
    before = openblas()
    assert before                       # numpy's OpenBLAS at least
    with single_threaded_blas():
        assert openblas() == [1] * len(before)
    assert openblas() == before


@pytest.mark.parametrize("preset", [None, "1"])
def test_mkl_threads_default_to_the_processs_cpus_unless_set(preset):
    """PARDISO runs on every CPU the process may use (two threads were 21-23 % faster on
    benchmarks/fast_path.py here); a value the user (or dask's nanny) set is kept."""
    env = {k: v for k, v in os.environ.items() if k != "MKL_NUM_THREADS"}
    if preset:
        env["MKL_NUM_THREADS"] = preset
    code = ("import os, solver.core.linsolve; "
            "print(os.environ['MKL_NUM_THREADS'], len(os.sched_getaffinity(0)))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out[0] == (preset or out[1])


@pytest.mark.skipif("pardiso" not in available(), reason="pypardiso not installed")
def test_pardiso_loads_mkl_without_searching_the_file_system():
    """pypardiso globs all of sys.prefix for libmkl_rt when it cannot find it by name (a
    second, in a run's first step); solver.core.linsolve points it at the mkl package's file
    (here with glob.glob disabled in a fresh process), unless the user set the path."""
    env = {k: v for k, v in os.environ.items() if k != "PYPARDISO_MKL_RT"}
    code = ("import glob, os\n"
            "def boom(*a, **k): raise AssertionError('glob')\n"
            "glob.glob = boom\n"
            "from solver.core.linsolve import make_solver\n"
            "lin = make_solver('pardiso-single')\n"
            "print(type(lin).__name__, os.path.isfile(os.environ['PYPARDISO_MKL_RT']))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["Pardiso", "True"]


@pytest.mark.skipif("pardiso" not in available(), reason="pypardiso not installed")
def test_mkl_buffers_are_handed_back_and_pardiso_works_after(rng):
    """free_mkl_buffers (called by Pardiso.release, so at an FMU's fmi2Terminate): MKL's
    memory manager holds fewer bytes after it than after PARDISO's phase 0 alone
    (mkl_mem_stat), and a new factorization solves as before."""
    import ctypes
    from solver.core.linsolve import Pardiso, free_mkl_buffers
    lib = ctypes.CDLL(os.environ["PYPARDISO_MKL_RT"])
    stat = lib.MKL_Mem_Stat
    stat.restype, stat.argtypes = ctypes.c_int64, [ctypes.POINTER(ctypes.c_int)]
    count = ctypes.c_int(0)
    n = 2000
    A = sp.random(n, n, density=0.01, random_state=rng) + sp.identity(n) * n
    A = sp.csr_matrix(A + A.T)
    b = rng.normal(size=n)
    lin = Pardiso("single")
    lin.refactor(A, "x")
    x0 = lin.solve(b)
    for handle in lin._handles.values():
        handle.release()                                  # phase 0 only
    kept = stat(ctypes.byref(count))
    free_mkl_buffers()
    assert stat(ctypes.byref(count)) < kept
    lin.refactor(A, "x")
    assert np.array_equal(lin.solve(b), x0)
    lin.release()


@pytest.mark.skipif("pardiso" not in available(), reason="pypardiso not installed")
def test_pardiso_gathers_the_upper_triangle_again_for_a_new_pattern(rng):
    from solver.core.linsolve import Pardiso
    lin = Pardiso()
    for n in (30, 30, 40):
        A = sp.random(n, n, density=0.2, random_state=rng) + sp.identity(n) * n
        A = sp.csr_matrix(A + A.T)
        for scale in (1.0, 3.0):                       # the same pattern: cached gather
            b = rng.normal(size=n)
            lin.refactor(A * scale, "x")
            assert np.allclose((A * scale) @ lin.solve(b), b, atol=1e-10)
    ref = SuperLU()
    ref.factorize(A)
    assert np.allclose(ref.solve(b), lin.solve(b) * 3.0, atol=1e-10)


@pytest.mark.skipif("pardiso" not in available(), reason="pypardiso not installed")
def test_pardiso_solves_without_refinement_and_stays_exact_on_indefinite_matrices(rng):
    """Our iparm is in force (MKL's defaults refined every solution twice: three solves per
    Newton direction); a symmetric indefinite saddle-point matrix, which 1x1 pivoting must
    still handle (perturbed pivots, then refinement), solves to round-off."""
    from solver.core.linsolve import Pardiso
    n, m = 60, 12
    A = sp.random(n, n, density=0.1, random_state=rng)
    A = sp.csr_matrix(A @ A.T + sp.identity(n))                      # SPD
    lin = Pardiso()
    b = rng.normal(size=n)
    lin.refactor(A, "spd")
    assert np.allclose(A @ lin.solve(b), b, atol=1e-10)
    assert lin._active.p.iparm[6] == 0                               # refinement steps taken
    B = sp.random(m, n, density=0.3, random_state=rng) + sp.eye(m, n)
    KKT = sp.bmat([[A, B.T], [B, None]], format="coo")                # zero diagonal block,
    zeros = np.arange(n, n + m)                                       # stored (PARDISO's rule)
    KKT = sp.csr_matrix((np.r_[KKT.data, np.zeros(m)], (np.r_[KKT.row, zeros],
                                                        np.r_[KKT.col, zeros])))
    c = rng.normal(size=n + m)
    lin.refactor(KKT, "kkt")
    x = lin.solve(c)
    assert np.linalg.norm(KKT @ x - c) <= 1e-9 * np.linalg.norm(c)


@pytest.mark.skipif("pardiso" not in available(), reason="pypardiso not installed")
def test_single_precision_pardiso_solves_to_its_precision_and_falls_back_to_double(rng):
    """pardiso-single: a well-conditioned SPD matrix solves to single precision (not to
    round-off in double, so the float32 path is the one taken); a saddle-point matrix
    (perturbed pivots) and an SPD matrix of condition 1e9 (a first solve far off) are
    factorized again in double and solve to round-off; 'auto' is the single one."""
    from solver.core.linsolve import SINGLE_CHECK, Pardiso
    n, m = 60, 12
    A = sp.random(n, n, density=0.1, random_state=rng)
    A = sp.csr_matrix(A @ A.T + sp.identity(n))
    lin = make_solver("pardiso-single")
    assert isinstance(lin, Pardiso) and lin.name == "pardiso-single"
    assert make_solver("auto").name == "pardiso-single"
    b = rng.normal(size=n)
    lin.refactor(A, "spd")
    rel = np.linalg.norm(A @ lin.solve(b) - b) / np.linalg.norm(b)
    assert 1e-12 < rel < SINGLE_CHECK and lin.fallbacks == 0
    X = lin.solve(np.column_stack([b, -b]))                         # two right-hand sides
    assert np.allclose(X[:, 0], -X[:, 1]) and X.dtype == np.float64
    B = sp.random(m, n, density=0.3, random_state=rng) + sp.eye(m, n)
    KKT = sp.bmat([[A, B.T], [B, None]], format="coo")
    zeros = np.arange(n, n + m)
    KKT = sp.csr_matrix((np.r_[KKT.data, np.zeros(m)], (np.r_[KKT.row, zeros],
                                                        np.r_[KKT.col, zeros])))
    c = rng.normal(size=n + m)
    lin.refactor(KKT, "kkt")
    assert np.linalg.norm(KKT @ lin.solve(c) - c) <= 1e-9 * np.linalg.norm(c)
    assert lin.fallbacks == 1
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    bad = sp.csr_matrix((Q * np.logspace(0, -9, n)) @ Q.T)
    lin.refactor(bad, "ill")
    x = lin.solve(b)
    assert lin.fallbacks == 2
    assert np.linalg.norm(bad @ x - b) <= 1e-6 * np.linalg.norm(b)


def test_partial_refresh_assembles_only_contact_within_a_call_and_reaches_the_same_state():
    """Refactorizations within a Newton call take the smooth terms' tangent of the call's
    full assembly and the contact's anew (NewtonOptions.partial_refresh): on the lip
    gesture's first 0.03 s (coarse half face) fewer full assemblies than factorizations,
    the contact's tangent alone assembled instead, and the same lip outputs as with a
    full assembly at every factorization; with partial_reach 0 every refactorization away
    from the full assembly's state assembles everything. (Without Krylov directions, which
    assemble the contact's tangent for their own use.)"""
    from solver.app.gestures import gesture
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    runs = {}
    for partial, reach in ((False, 0.05), (True, 0.05), (True, 0.0)):
        sim = Simulation(parse_scene(gesture(0.03)), level="coarse", half=True,
                         **REFERENCE_BALANCED)
        sim.face.model.newton_options.partial_refresh = partial
        sim.face.model.newton_options.partial_reach = reach
        sim.face.model.newton_options.krylov = False
        rows = []
        sim.run(on_record=lambda s, row: rows.append(row))
        sysm, lin = sim.face.model.system(), sim.face.model.linear_solver
        runs[partial, reach] = (lin.factorizations, dict(sysm.counters), rows)
        if partial:                     # the contact's part: nonzero where slaves touch
            u = sim.face.u.ravel()
            touching = any(t.n_active for t in sim.contact)
            assert touching and np.abs(sysm.nonsmooth_tangent(u)).max() > 0.0
        sim.release()
    (f0, c0, rows0), (f1, c1, rows1) = runs[False, 0.05], runs[True, 0.05]
    f2, c2, _ = runs[True, 0.0]
    assert c0["assemblies"] == f0 and c0["partial_tangents"] == 0
    assert c1["assemblies"] < f1 and c1["partial_tangents"] >= f1 - c1["assemblies"] > 0
    assert c2["assemblies"] == f2
    for a, b in zip(rows0, rows1):
        assert abs(a["lip_protrusion"] - b["lip_protrusion"]) < 1e-4
        assert abs(a["lip_aperture"] - b["lip_aperture"]) < 1e-4


@pytest.mark.parametrize("refresh, most", [(0.0, None), (np.inf, 2)])
def test_substeps_share_a_factorization_only_while_the_damping_matrix_is_held(refresh, most):
    """Newton's key is the substep size (to rounding: the last substep of a caller step
    lands on its end, t1 - t, a few ulps off) and the damping matrix's generation: rebuilt
    at every substep (refresh 0, the default) the tangent's largest part changes, and each
    substep factorizes; held, the ten equal substeps share a factorization or two."""
    model = _bar()
    tr = Transient(model, hold="step", fixed_step=0.001)
    tr.damping.refresh = refresh
    stats = tr.advance(0.01)
    assert stats.converged and stats.substeps == 10
    assert tr.damping.builds == (10 if refresh == 0.0 else 1)
    if most is None:
        assert stats.factorizations >= stats.substeps
    else:
        assert stats.factorizations <= most


FAST_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "fast_path.py"


def _fast_path(tmp_path, *args):
    return subprocess.run([sys.executable, str(FAST_PATH), *args], capture_output=True,
                          text=True, cwd=tmp_path, timeout=600)


@pytest.mark.parametrize("knob, message", [("tol=0.01", "expected group.name=value"),
                                           ("newton.rtol", "expected group.name=value"),
                                           ("mesh.level=1", "the group must be one of")])
def test_fast_path_refuses_a_knob_without_group_or_value_or_of_another_group(tmp_path, knob,
                                                                             message):
    run = _fast_path(tmp_path, "--set", knob)
    assert run.returncode == 2 and message in run.stderr


def test_fast_path_tallies_a_tiny_run_with_its_knobs(tmp_path):
    """benchmarks/fast_path.py on 0.02 s of case b: the knobs typed (int, float, bool) and
    applied (transient.fixed_step 5 ms: two substeps per 10 ms record, summed over the two
    records; newton.reuse false: no factorization reused), a row with the
    penetration and the machine gauge before and after, the records saved."""
    run = _fast_path(tmp_path, "--only", "b", "--paths", "new", "--duration", "0.02",
                     "--set", "transient.fixed_step=0.005", "--set", "newton.reuse=false",
                     "--set", "newton.max_iter=30", "--set", "lips.smoothing=0.0",
                     "--records", "records.json", "--md", "table.md")
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    header, _, values = (tmp_path / "table.md").read_text().splitlines()
    row = dict(zip(header.split(" | "), values.split(" | ")))
    assert row["set"] == ("transient.fixed_step=0.005 newton.reuse=False newton.max_iter=30 "
                          "lips.smoothing=0.0")
    assert int(row["substeps"]) == 4 and row["failed"] == "-"
    # no reuse: at least one factorization per Newton iteration (the count of Newton's
    # iterations leaves out its extra solves, e.g. a direction made again)
    assert int(row["factorizations"]) >= int(row["newton_its"]) >= 4
    assert float(row["penetration_mm"]) >= 0.0
    assert len([float(x) for x in row["probe_s"].split(" / ")]) == 2
    rec = json.loads((tmp_path / "records.json").read_text())
    assert [round(r["time"], 6) for r in rec["b/new"]] == [0.0, 0.01, 0.02]


def test_after_a_dropped_reused_step_a_call_tries_no_more_reused_directions(monkeypatch):
    """krylov_after_stale: once a reused factorization's step has been dropped in a Newton
    call, the call's later iterates skip the plain reused direction, so that no call
    drops more than one step; without it the lip gesture has calls that drop several.
    The outputs agree to a small multiple of Newton's last update."""
    import solver.core.transient as T
    calls = []
    newton = T.newton

    def recording(*args, **kwargs):
        out = newton(*args, **kwargs)
        calls.append(out[2].stale_steps)
        return out
    monkeypatch.setattr(T, "newton", recording)
    runs = gesture_both_ways("krylov_after_stale", 0.06,
                             lambda sim: (max(calls), calls.clear())[0])
    assert runs[False][0] >= 2 and runs[True][0] == 1
    assert_same_lips(runs[False][1], runs[True][1], tol=1e-3)
