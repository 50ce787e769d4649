r"""Offline training of a realtime (reduced) model from full-order snapshot runs.

1. Snapshots: full-order transient runs of the scene's model at the realtime knobs
   (coarse generic half face, loose tolerances) under random activation patterns of the
   scene's driven muscles: `runs` runs of `duration` s (`random_schedules`), `jaw_runs`
   that move the jaw as well (`random_jaw`), `phrase_runs` speech-like phrases of
   `phrase_duration` s (`random_phrase`, stream `phrase_seed`) and `jaw_phrase_runs`
   phrases that all move the jaw (stream `jaw_phrase_seed`); the displacements are
   recorded every `interval` s. The poses covered are the model's "jaw_envelope". A run
   that takes longer than max_wall keeps the snapshots it has. Runs are independent
   tasks: through a dask client (solver.sweep.Sweep, `snapshot_task`) or in this process.
2. Basis: POD of the snapshots on the free DOFs (solver.rom.pod), size by captured energy,
   in two stages where the jaw moves: V_1 of the muscle runs, then V_2 of what V_1 leaves
   of the jaw runs (u - V_1 V_1^T u), to `energy` and `jaw_energy`; V = [V_1 V_2].
3. Cubature: ECSW (solver.rom.ecsw) over up to `ecsw_states` snapshots projected on the
   basis, u = V V^T u_j + (u_j on the prescribed DOFs: the jaw's lifting), with their
   activations (tissue + stiffening per brick).
4. Matrices: M_r = V^T M V, K0_r = V^T K_0 V (rest passive stiffness, for the damping).
5. Trust calibration: the reduced model runs `calibration_runs` of the training patterns,
   the first jaw run and the first phrase of each kind (without and with the jaw);
   the threshold is `trust_factor` times the largest full-order residual rho met
   (solver.rom.simulation), at least `trust_floor`. The largest displacement and lip
   output differences to the full runs of those patterns are stored in meta.

The random patterns, and why phrases and a two-stage basis: docs/method.md, section
'Training'.
"""

import time

import numpy as np

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.face.jaw import JAW_INPUTS, JAW_RANGES
from solver.app.scene import Schedule
from solver.rom.ecsw import ecsw, scale_rows
from solver.rom.kernels import element_forces
from solver.rom.pod import captured_energy, pod_basis
from solver.rom.store import model_key, model_path, save_model


def _pwl(muscle, times, values):
    t, v = [times[0]], [values[0]]
    for a, b in zip(times[1:], values[1:]):
        if a > t[-1] + 1e-9:
            t.append(a)
            v.append(b)
    return Schedule(muscle, "pwl", tuple(float(x) for x in t), tuple(float(x) for x in v))


def random_schedules(rng, muscles, duration, primary=None):
    """A random activation pattern: a tuple of solver.app.scene.Schedule (module docstring).
    primary: a muscle that takes part at a high level (U(0.6, 1))."""
    muscles = list(muscles)
    out = []
    if len(muscles) >= 5 and primary is None and rng.random() < 0.25:
        chosen = rng.choice(muscles, rng.integers(5, len(muscles) + 1), replace=False)
        levels = rng.uniform(0.0, 0.6, len(chosen))
    else:
        others = [m for m in muscles if m != primary]
        n = rng.integers(0 if primary else 1, min(3, len(others)) + 1)
        chosen = ([primary] if primary else []) + list(rng.choice(others, n, replace=False))
        levels = rng.uniform(0.1, 1.0, len(chosen))
        if primary:
            levels[0] = rng.uniform(0.6, 1.0)
    for m, level in zip(chosen, levels):
        t0 = rng.uniform(0.0, 0.05)
        t1 = t0 + rng.uniform(0.05, 0.1)
        times, values = [0.0, t0, t1], [0.0, 0.0, level]
        if rng.random() < 0.5 and t1 + 0.04 < duration:
            t2 = t1 + rng.uniform(0.0, 0.03)
            t3 = min(t2 + rng.uniform(0.05, 0.1), duration)
            times += [t2, t3]
            values += [level, rng.uniform(0.0, 0.5 * level)]
        times.append(max(duration, times[-1]))
        values.append(values[-1])
        out.append(_pwl(str(m), times, values))
    return tuple(out)


def _ramp(rng, name, level, duration):
    """A schedule: 0 -> level over U(0.05, 0.15) s from U(0, 0.05) s, back to
    U(0, 0.5) level one time in two."""
    t0 = rng.uniform(0.0, 0.05)
    t1 = min(t0 + rng.uniform(0.05, 0.15), duration)
    times, values = [0.0, t0, t1], [0.0, 0.0, level]
    if rng.random() < 0.5 and t1 + 0.04 < duration:
        t2 = min(t1 + rng.uniform(0.0, 0.03), duration)
        times += [t2, min(t2 + rng.uniform(0.04, 0.1), duration)]
        values += [level, rng.uniform(0.0, 0.5) * level]
    times.append(max(duration, times[-1]))
    values.append(values[-1])
    return _pwl(name, times, values)


def random_jaw(rng, duration, opening=(0.0, JAW_RANGES["jaw_opening"][1])):
    """Random jaw schedules (module docstring): the opening to U(opening), and one time in
    three the protrusion to U(JAW_RANGES)."""
    out = [_ramp(rng, "jaw_opening", rng.uniform(*opening), duration)]
    if rng.random() < 1.0 / 3.0:
        out.append(_ramp(rng, "jaw_protrusion", rng.uniform(*JAW_RANGES["jaw_protrusion"]),
                         duration))
    return tuple(out)


def random_phrase(rng, muscles, duration, jaw=False):
    """A speech-like activation pattern (module docstring, step 1): Schedule tuple over
    the muscles (and jaw_opening, with jaw) that leave 0 at some time."""
    muscles = list(muscles)
    names = muscles + (["jaw_opening"] if jaw else [])
    starts = np.sort(rng.uniform(0.0, 0.7 * duration, int(rng.integers(2, 4))))
    starts[0] = rng.uniform(0.0, 0.03)
    level = {m: 0.0 for m in names}
    times = {m: [0.0] for m in names}
    values = {m: [0.0] for m in names}
    for t0 in starts:
        t1 = min(t0 + rng.uniform(0.02, 0.08), duration)
        k = min(int(rng.integers(1, 6)), len(muscles))     # fewer driven: all of them
        chosen = set(rng.choice(muscles, k, replace=False))
        for m in names:
            if m == "jaw_opening":
                new = (rng.uniform(0.0, JAW_RANGES[m][1]) if rng.random() < 0.7
                       else level[m])
            elif m in chosen:
                new = rng.uniform(0.1, 1.0)
            else:
                new = level[m] if rng.random() < 0.3 else 0.0
            times[m] += [max(t0, times[m][-1]), t1]
            values[m] += [level[m], new]
            level[m] = new
    out = []
    for m in names:
        times[m].append(duration)
        values[m].append(values[m][-1])
        if max(values[m]) > 0:
            out.append(_pwl(m, times[m], values[m]))
    return tuple(out)


def drive(sim, schedules, duration, interval, on_record=None, max_wall=None):
    """Step sim through schedules (Schedule tuple) to duration at interval; lip outputs
    (list of dicts with time) at every interval (t = 0 included). max_wall (s): stop
    early once the run has taken that long (the rows so far)."""
    times = np.arange(1, int(round(duration / interval)) + 1) * interval
    rows = [{"time": 0.0, **sim.outputs()}]
    t_start = time.perf_counter()
    for t in times:
        if max_wall is not None and time.perf_counter() - t_start > max_wall:
            break
        values = {m: 0.0 for m in sim.face.muscles}
        values.update({s.muscle: s.value(t) for s in schedules if s.muscle not in JAW_INPUTS})
        sim.set_activations(values)
        jaw = {s.muscle: s.value(t) for s in schedules if s.muscle in JAW_INPUTS}
        if jaw:
            sim.set_jaw(jaw.get("jaw_opening"), jaw.get("jaw_protrusion"))
        stats = sim.step(float(t))
        if not stats.converged:
            raise RuntimeError(f"step to t = {t:.4g} s failed: {stats.reason}")
        rows.append({"time": float(t), **sim.outputs()})
        if on_record is not None:
            on_record(sim)
    return rows


def snapshot_task(task, scene, sim=None):
    """One full-order snapshot run (a dask task): task {"label", "schedules", "duration",
    "interval", "max_wall" (optional, s: the run stops there, keeping its snapshots),
    **Simulation keyword arguments}; scene a solver.app.scene.Scene; sim: a full-order
    Simulation of scene to reuse (reset to rest). Returns {"label", "U" (3 n, s)
    displacements, "A" (s, 10) activations, "P" (s, 2) jaw poses, "rows", "wall_s",
    "error"}."""
    from solver.app.simulation import Simulation
    out = {"label": task.get("label", ""), "error": ""}
    kw = {k: v for k, v in task.items()
          if k not in ("label", "schedules", "duration", "interval", "max_wall")}
    U, A, P = [], [], []

    def keep(sim):
        U.append(sim.face.u.ravel().copy())
        A.append(sim.face.activation.start.copy())
        P.append(np.array(sim.jaw))
    try:
        t0 = time.perf_counter()
        if sim is None:
            sim = Simulation(scene, **kw)
        else:
            sim.set_state({"t": 0.0, "u": 0.0 * sim.face.u, "v": 0.0 * sim.face.u,
                           "activation": np.zeros(len(MUSCLE_NAMES)), "h": 1e-3})
        out["rows"] = drive(sim, task["schedules"], task["duration"], task["interval"], keep,
                            task.get("max_wall"))
        out["wall_s"] = time.perf_counter() - t0
    except Exception as exc:                       # reported per task
        out["error"] = f"{type(exc).__name__}: {exc}"
        return out
    out["U"], out["A"], out["P"] = np.array(U).T, np.array(A), np.array(P).reshape(-1, 2)
    return out


def snapshot_tasks(scene, runs, duration, interval, seed, max_wall=None, jaw_runs=0,
                   phrase_runs=0, phrase_duration=0.2, phrase_seed=7, jaw_phrase_runs=0,
                   jaw_phrase_seed=11):
    """The training runs' tasks (module docstring): `runs` muscle patterns, then
    `jaw_runs` that move the jaw as well, then `phrase_runs` phrases (of
    phrase_duration s; every third moves the jaw where the face has one), then
    `jaw_phrase_runs` phrases that all move it (their own stream jaw_phrase_seed; none
    without a jaw)."""
    rng = np.random.default_rng(seed)
    driven = list(scene.driven)
    order = list(rng.permutation(driven))
    tasks = [{"label": f"pattern {i}", "schedules": random_schedules(
                 rng, driven, duration, order[i % len(order)] if i < 2 * len(order) else None)}
             for i in range(runs)]
    for i in range(jaw_runs):
        muscles = (rng.choice(driven, min(int(rng.integers(1, 4)), len(driven)), replace=False)
                   if driven else [])
        sched = tuple(_ramp(rng, str(m), rng.uniform(0.1, 1.0), duration) for m in muscles)
        sched += random_jaw(rng, duration, (5.0, JAW_RANGES["jaw_opening"][1]))
        tasks.append({"label": f"jaw pattern {i}", "schedules": sched})
    for t in tasks:
        t.update(duration=duration, interval=interval, max_wall=max_wall)
    rng = np.random.default_rng(phrase_seed)
    for i in range(phrase_runs):
        jaw = jaw_runs > 0 and i % 3 == 2
        tasks.append({"label": f"{'jaw ' if jaw else ''}phrase {i}",
                      "schedules": random_phrase(rng, driven, phrase_duration, jaw),
                      "duration": phrase_duration, "interval": interval,
                      "max_wall": max_wall})
    rng = np.random.default_rng(jaw_phrase_seed)
    for i in range(jaw_phrase_runs if jaw_runs > 0 else 0):
        tasks.append({"label": f"jaw phrase {phrase_runs + i}",
                      "schedules": random_phrase(rng, driven, phrase_duration, True),
                      "duration": phrase_duration, "interval": interval,
                      "max_wall": max_wall})
    return tasks


def jaw_envelope(tasks):
    """{jaw input: [lo, hi]} of the poses the tasks' schedules reach (0 included: the
    jaw rests closed where no schedule moves it)."""
    env = {name: [0.0, 0.0] for name in JAW_INPUTS}
    for t in tasks:
        for s in t["schedules"]:
            if s.muscle in env:
                lo, hi = env[s.muscle]
                env[s.muscle] = [min(lo, min(s.values)), max(hi, max(s.values))]
    return env


def _task_file(folder, scene, task):
    import hashlib
    import json
    key = json.dumps([model_key(scene), repr(task["schedules"]), task["duration"],
                      task["interval"], task.get("max_wall")], sort_keys=True)
    return folder / f"snap-{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"


def _save_result(path, r):
    import json
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, U=r["U"], A=r["A"], P=r["P"], rows=np.array(json.dumps(r["rows"])),
             wall_s=r["wall_s"])


def _load_result(path, label):
    import json
    with np.load(path, allow_pickle=False) as f:
        return {"label": label, "error": "", "U": f["U"], "A": f["A"], "P": f["P"],
                "rows": json.loads(str(f["rows"])), "wall_s": float(f["wall_s"])}


def collect(scene, tasks, client=None, progress=True, sim=None, folder=None, budget=None):
    """Run the snapshot tasks (on a dask client, or here, reusing the full-order sim if
    given); their results in order. folder: where finished runs are kept (.npz per
    task) and found again by a later call with the same tasks. budget (s, dask only):
    the tasks not finished by then are cancelled and left out (None in the results;
    a later call with the same folder runs them)."""
    files = [_task_file(folder, scene, t) if folder else None for t in tasks]
    results = [_load_result(f, t["label"]) if f and f.is_file() else None
               for f, t in zip(files, tasks)]
    todo = [i for i, r in enumerate(results) if r is None]
    if budget is not None and budget <= 0:          # the kept runs only
        todo = []
    t0 = time.perf_counter()

    def done(i, r, count):
        results[i] = r
        if files[i] and not r["error"]:
            _save_result(files[i], r)
        if progress:
            print(f"[{count}/{len(todo)} {time.perf_counter() - t0:5.0f} s] {r['label']}: "
                  f"{r['error'] or '%.1f s wall, %d snapshots' % (r['wall_s'], r['U'].shape[1])}",
                  flush=True)
    if client is None:
        for count, i in enumerate(todo, 1):
            done(i, snapshot_task(tasks[i], scene, sim), count)
    else:
        from dask.distributed import as_completed
        from dask.distributed import TimeoutError as DaskTimeout
        futures = {client.submit(snapshot_task, tasks[i], scene, pure=False): i for i in todo}
        try:
            for count, f in enumerate(as_completed(futures, timeout=budget), 1):
                done(futures[f], f.result(), count)
        except (DaskTimeout, TimeoutError):
            left = [f for f in futures if not f.done()]
            client.cancel(left)
            if progress:
                print(f"budget of {budget} s spent: {len(left)} runs left out", flush=True)
    failed = [r["label"] + ": " + r["error"] for r in results if r and r["error"]]
    if failed:
        raise RuntimeError("snapshot runs failed: " + "; ".join(failed))
    return results


def brick_data(sim, V):
    """All bricks as a solver.rom.reduced.ReducedOperator (weights 1)."""
    from solver.rom.reduced import ReducedOperator
    r = V.shape[1]
    n = sim.anatomy.mesh.n_bricks
    return ReducedOperator(sim, V, np.arange(n), np.ones(n), np.zeros((r, r)),
                           np.zeros((r, r)))


def cubature(sim, V, U, A, tol=1e-2, states=150, max_elements=None):
    """ECSW over up to `states` snapshot columns of U (with activations A), projected on
    V on the free DOFs, as they are on the prescribed ones (the jaw): (bricks, weights,
    relative residual)."""
    op = brick_data(sim, V)
    mesh = sim.anatomy.mesh
    nz = np.flatnonzero(np.abs(U).max(axis=0) > 0)
    pick = nz[np.unique(np.linspace(0, len(nz) - 1, min(states, len(nz))).astype(int))]
    r, N = V.shape[1], mesh.n_bricks
    fixed = np.setdiff1d(np.arange(V.shape[0]), sim.face.model.system().free)
    G = np.empty((len(pick) * r, N))
    fe = np.empty((N, 24))
    for j, c in enumerate(pick):
        u = V @ (V.T @ U[:, c])
        u[fixed] = U[fixed, c]
        u = u.reshape(-1, 3)
        element_forces(u, mesh.bricks, op.dndX, op.wgp, op.params, op.form, op.sparams,
                       op.stiffening_factors(A[c]), fe)
        G[j * r:(j + 1) * r] = np.einsum("ed,edr->re", fe, op.Ve)
    G, b = scale_rows(G, G.sum(axis=1), r)
    w, res = ecsw(G, b, tol, max_elements)
    sel = np.flatnonzero(w > 0)
    return sel, w[sel], res


def reduced_matrices(sim, V):
    """(M_r, K0_r): V^T M V with the lumped masses, V^T K_0 V (rest passive tangent)."""
    from solver.core.terms.inertia import lumped_masses, passive_tangent
    from solver.core.units import kg_per_m3
    mesh = sim.anatomy.mesh
    m3 = np.repeat(lumped_masses(mesh, kg_per_m3(sim.scene.density)), 3)
    M_r = V.T @ (m3[:, None] * V)
    Ve = brick_data(sim, V).Ve
    ke = passive_tangent(sim.face.model.elasticity)
    K0_r = np.einsum("edr,eds->rs", Ve, ke @ Ve)
    return M_r, 0.5 * (K0_r + K0_r.T)


def train(scene, sim=None, runs=24, duration=0.2, interval=0.005, seed=0, client=None,
          energy=1.0 - 1e-6, r_max=60, ecsw_tol=1e-2, ecsw_states=150, calibration_runs=3,
          trust_factor=3.0, trust_floor=0.05, out=None, progress=True, max_wall=40.0,
          sim_only=False, budget=None, jaw_runs=12, provenance=None, jaw_energy=None,
          phrase_runs=0, phrase_duration=0.2, phrase_seed=7, jaw_phrase_runs=0,
          jaw_phrase_seed=11):
    """Train, save and return the path of the realtime model of scene (a Scene at the
    realtime knobs; sim: its full-order Simulation if already built). Finished snapshot
    runs are kept in <cache>/rom/snapshots/<key> and reused (sim_only=True: not kept).
    provenance: a dict stored in the model's meta (e.g. scene name, command, commit)."""
    from solver.app.simulation import Simulation
    t_start = time.perf_counter()
    if sim is None:
        from solver.app.fidelity import apply_fidelity
        scene = apply_fidelity(scene, "realtime")
        sim = Simulation(scene)
    scene = sim.scene
    base = scene.with_overrides(schedules=())
    jaw_runs = jaw_runs if sim.face.jaw is not None else 0
    tasks = snapshot_tasks(base, runs, duration, interval, seed, max_wall, jaw_runs,
                           phrase_runs, phrase_duration, phrase_seed, jaw_phrase_runs,
                           jaw_phrase_seed)
    from solver.rom.store import cache_dir, key_hash
    folder = cache_dir() / "snapshots" / key_hash(model_key(base))
    results = collect(base, tasks, client, progress, sim, None if sim_only else folder,
                      budget)
    kept = [i for i, r in enumerate(results) if r is not None]
    tasks, results = [tasks[i] for i in kept], [results[i] for i in kept]
    t_snap = time.perf_counter() - t_start
    free = sim.face.model.system().free
    U = np.hstack([r["U"] for r in results])
    A = np.vstack([r["A"] for r in results])
    jaw = np.concatenate([np.full(r["U"].shape[1], t["label"].startswith("jaw"))
                          for t, r in zip(tasks, results)])
    Vf, sigma = pod_basis(U[free][:, ~jaw], energy, r_max=r_max)
    r1 = Vf.shape[1]
    if jaw.any():                  # stage 2: what V_1 leaves of the jaw runs
        rest = U[free][:, jaw]
        rest = rest - Vf @ (Vf.T @ rest)
        V2, _ = pod_basis(rest, jaw_energy or energy, r_max=r_max)
        Vf, _ = np.linalg.qr(np.hstack([Vf, V2]))
    V = np.zeros((U.shape[0], Vf.shape[1]))
    V[free] = Vf
    t_pod = time.perf_counter()
    bricks, weights, res = cubature(sim, V, U, A, ecsw_tol, ecsw_states)
    t_ecsw = time.perf_counter()
    M_r, K0_r = reduced_matrices(sim, V)
    arrays = {"V": V, "bricks": bricks, "weights": weights, "M_r": M_r, "K0_r": K0_r,
              "sigma": sigma, "trust_threshold": np.array([np.inf])}
    r = V.shape[1]
    meta = {"scene": scene.name, **(provenance or {}), "key": model_key(scene),
            "basis_size": r, "jaw_modes": r - r1, "runs_used": len(results),
            "captured_energy": captured_energy(sigma, r1), "snapshots": int(U.shape[1]),
            "runs": runs, "jaw_runs": jaw_runs, "jaw_envelope": jaw_envelope(tasks),
            "phrase_runs": phrase_runs, "phrase_duration": phrase_duration,
            "phrase_seed": phrase_seed, "jaw_phrase_runs": jaw_phrase_runs,
            "jaw_phrase_seed": jaw_phrase_seed,
            "duration": duration, "interval": interval, "seed": seed,
            "bricks_selected": int(len(bricks)), "bricks_total": int(sim.anatomy.mesh.n_bricks),
            "ecsw_tol": ecsw_tol, "ecsw_residual": res, "snapshot_s": t_snap,
            "pod_s": t_pod - t_start - t_snap, "ecsw_s": t_ecsw - t_pod}
    pick = list(range(min(calibration_runs, len(tasks))))      # and a jaw run, if any,
    for kind in ("jaw pattern", "phrase", "jaw phrase"):        # and the first phrases
        pick += [i for i, t in enumerate(tasks) if t["label"].startswith(kind)][:1]
    calib = calibrate(scene, (arrays, meta), [tasks[i] for i in pick],
                      [results[i] for i in pick], sim)
    arrays["trust_threshold"] = np.array([max(trust_factor * calib["rho_max"], trust_floor)])
    meta.update(calib, trust_threshold=float(arrays["trust_threshold"][0]),
                train_s=time.perf_counter() - t_start)
    path = save_model(out or model_path(scene), arrays, meta)
    if progress:
        print(f"realtime model: {r} modes ({r1} of the muscle runs: "
              f"{meta['captured_energy']:.8f} of their energy; {r - r1} of the jaw runs), "
              f"{len(bricks)} of {meta['bricks_total']} bricks (ECSW residual {res:.2g}), "
              f"trust threshold {meta['trust_threshold']:.3g}; trained in "
              f"{meta['train_s']:.0f} s -> {path}", flush=True)
    return path


def calibrate(scene, model, tasks, results, sim=None):
    """Run the reduced model on training patterns: the largest trust residual rho and
    the largest differences to the full runs (displacement, lip aperture, protrusion)."""
    from solver.rom.simulation import ReducedSimulation
    rom = ReducedSimulation(scene, loaded_anatomy=sim.anatomy if sim else None,
                            rom_model=model, trust="off")
    rho, du, dap, dpr = [0.0], [0.0], [0.0], [0.0]
    zero = rom.get_state()
    for task, full in zip(tasks, results):
        rom.set_state(zero)
        rom.t = 0.0
        k = [0]

        def check(s):
            rho.append(s.trust_residual())
            du.append(float(np.abs(s.u.ravel() - full["U"][:, k[0]]).max()))
            k[0] += 1
        rows = drive(rom, task["schedules"], task["interval"] * full["U"].shape[1],
                     task["interval"], check)
        for a, b in zip(rows, full["rows"]):
            dap.append(abs(a["lip_aperture"] - b["lip_aperture"]))
            dpr.append(abs(a["lip_protrusion"] - b["lip_protrusion"]))
    return {"rho_max": max(rho), "calibration_runs": len(tasks),
            "calibration_max_du_mm": max(du), "calibration_max_aperture_mm": max(dap),
            "calibration_max_protrusion_mm": max(dpr)}

