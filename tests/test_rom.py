"""The realtime reduced-order model (solver.rom), on a tiny training set.

The session fixture `trained` (conftest.py) trains a model in this process: the coarse
generic half face with OOP, RIS and DLI driven, teeth and lip contact, 3 full-order runs
of 0.05 s (5 ms snapshots). The tests check its parts (POD, ECSW), its answer against the
full model on a training pattern, the .npz round trip, the trust check and the Simulation
integration (tests/test_rom_online.py: the fast online step; tests/test_rom_entry.py: scene
files, the command line and the FMU).
"""

import warnings

import numpy as np
import pytest

from solver.app.scene import Scene
from solver.entry import open_simulation


def test_pod_basis_is_orthonormal_and_reproduces_the_snapshots(trained):
    V, free = trained["arrays"]["V"], trained["full"].face.model.system().free
    r = V.shape[1]
    assert np.allclose(V.T @ V, np.eye(r), atol=1e-10)
    fixed = np.setdiff1d(np.arange(V.shape[0]), free)
    assert np.all(V[fixed] == 0.0)                         # constrained DOFs stay at 0
    U = np.hstack([res["U"] for res in trained["results"]])[free]   # jaw: the lifting's
    err = np.linalg.norm(U - V[free] @ (V[free].T @ U)) / np.linalg.norm(U)
    assert err <= np.sqrt(1.0 - 0.999999) * 1.01           # the energy criterion
    assert trained["meta"]["captured_energy"] >= 0.999999


def test_ecsw_weights_are_nonnegative_and_reproduce_the_projected_force(trained):
    from rom_reference import ReferenceOperator
    a, full = trained["arrays"], trained["full"]
    V = a["V"]
    assert np.all(a["weights"] > 0) and len(a["bricks"]) < full.anatomy.mesh.n_bricks / 3
    r = V.shape[1]
    zero = np.zeros((r, r))
    n = full.anatomy.mesh.n_bricks
    cub = ReferenceOperator(full, V, a["bricks"], a["weights"], zero, zero)
    every = ReferenceOperator(full, V, np.arange(n), np.ones(n), zero, zero)
    res = trained["results"][0]
    errs = []
    for j in range(0, res["U"].shape[1], 2):
        q = V.T @ res["U"][:, j]
        for op in (cub, every):
            op.set_pose(res["P"][j], res["P"][j])
        f_all = every.bricks_part(q, res["A"][j], False)[0]
        f_cub = cub.bricks_part(q, res["A"][j], False)[0]
        errs.append(np.linalg.norm(f_cub - f_all) / np.linalg.norm(f_all))
    assert max(errs) < 0.05, errs


def test_rom_follows_the_full_model_on_a_training_pattern(trained):
    from solver.rom.train import drive
    rom = open_simulation(trained["scene"], fidelity="realtime", rom_model=trained["path"],
                          loaded_anatomy=trained["full"].anatomy, trust="warn",
                          check_every=10)
    task, res = trained["tasks"][0], trained["results"][0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")                     # no trust warning on training
        rows = drive(rom, task["schedules"], task["duration"], task["interval"])
    for key in ("lip_aperture", "lip_protrusion"):
        d = max(abs(a[key] - b[key]) for a, b in zip(rows, res["rows"]))
        assert d < 0.05, (key, d)
    assert np.abs(rom.u.ravel() - res["U"][:, -1]).max() < 0.1
    assert rom.trust_history and max(r for _, r in rom.trust_history) <= rom.trust_threshold
    assert rom.last.converged and rom.mode == "rom"


def test_model_file_round_trip_and_key_check(trained, tmp_path):
    from solver.core.errors import FaceFMUError
    from solver.rom.store import load_model, model_key, save_model
    a, meta = trained["arrays"], trained["meta"]
    path = save_model(tmp_path / "copy.npz", a, meta)
    b, meta2 = load_model(path, model_key(trained["scene"]))
    assert meta2 == meta
    assert all(np.array_equal(a[k], b[k]) for k in a)
    other = trained["scene"].with_overrides(lip_contact=False)
    with pytest.raises(FaceFMUError, match="other settings"):
        load_model(path, model_key(other))
    # a non-default lip penalty is part of the key; the default leaves earlier keys as
    # they were (no such field)
    assert "lip_penalty" not in model_key(trained["scene"])
    soft = trained["scene"].with_overrides(lip_penalty=0.3)
    assert model_key(soft)["lip_penalty"] == 0.3
    with pytest.raises(FaceFMUError, match="other settings"):
        load_model(path, model_key(soft))


def test_trust_check_fires_far_outside_the_training_range(trained):
    from solver.rom.simulation import TrustWarning
    # ten times the muscles' peak forces (at 6x the first check's rho was 9.8 with the
    # first implementation's damping, lagged over 5 substeps, and 4.8 with the exact
    # per-substep damping of the fast method: at the threshold of this tiny model)
    scene = trained["scene"].with_overrides(force_scale={"OOP": 10.0, "RIS": 10.0})
    rom = open_simulation(scene, fidelity="realtime", rom_model=trained["path"],
                          loaded_anatomy=trained["full"].anatomy, check_every=5)
    rom.set_activations({"OOP": 1.0, "RIS": 1.0})
    with pytest.warns(TrustWarning, match="switching to the full model"):
        for k in range(1, 5):
            assert rom.step(0.005 * k).converged
            if rom.mode == "full":
                break
    assert rom.mode == "full" and rom.trust_history[-1][1] > rom.trust_threshold
    assert rom.outputs()["rom_fallbacks"] == 1                  # counted (an FMU output)
    # the full model's share of the simulated time: the step it redid, then the next one
    assert rom.outputs()["rom_full_time"] == pytest.approx(0.005, abs=1e-12)
    assert rom.step(rom.t + 0.005).converged
    assert rom.outputs()["rom_full_time"] == pytest.approx(0.010, abs=1e-12)
    assert rom.get_state()["full_time"] == pytest.approx(0.010, abs=1e-12)


def test_a_look_at_the_state_leaves_the_run_as_it_was(trained):
    """get_state(fresh=False) (the stress checks' look) changes nothing: the run equals
    one without it, bit for bit; get_state() drops the stepper's caches (so that a step
    repeats exactly after set_state), which changes the Newton path."""
    def run(look):
        rom = open_simulation(trained["scene"], fidelity="realtime",
                              rom_model=trained["path"],
                              loaded_anatomy=trained["full"].anatomy)
        rom.set_activations({"OOP": 1.0, "RIS": 0.5})
        iterations = 0
        for k in range(1, 9):
            if look is not None:
                rom.get_state(fresh=look)
            iterations += rom.step(0.002 * k).newton_iterations
        return rom.u.copy(), iterations
    plain, n_plain = run(None)
    looked, n_looked = run(False)
    assert np.array_equal(plain, looked) and n_plain == n_looked
    fresh, n_fresh = run(True)
    assert n_fresh != n_plain or not np.array_equal(fresh, plain)


def test_contact_penetration_beyond_the_tolerance_falls_back(trained, monkeypatch):
    """The reduced contact's deepest penetration (the kernels' gaps at the last force
    evaluation) is the one measured outside the model (solver.validation.stability.Probe,
    on the reconstructed displacement); past the contact tolerance the step is redone by
    the full model, with a warning that names it. The kernel measures to the master's
    triangles, which stay within a 32nd of a quad's warp of its bilinear face, where the
    probe measures: pressed by OOP, the upper lip's inner slit face next to the mid-line
    warps by 0.5 mm, and the lower lip's inner slit node pressed into it is 0.0096 mm
    from the kernel's triangle and 0.0170 mm from the bilinear face; hence 8e-3 mm."""
    import solver.rom.simulation as rs
    from solver.validation.stability import Probe
    rom = open_simulation(trained["scene"], fidelity="realtime", rom_model=trained["path"],
                          loaded_anatomy=trained["full"].anatomy)
    probe = Probe(rom.anatomy)
    rom.set_activations({"OOP": 1.0})
    deepest = 0.0
    for k in range(1, 7):                                       # lips pressed by OOP
        assert rom.step(0.005 * k).converged and rom.mode == "rom"
        lips, teeth = probe.penetrations(rom.u)
        assert rom.stepper.penetration == pytest.approx(max(lips, teeth), abs=8e-3)
        deepest = max(deepest, rom.stepper.penetration)
    assert 0.0 < deepest < rs.TOLERANCE
    monkeypatch.setattr(rs, "TOLERANCE", deepest / 2)          # the same run, a tighter limit
    rom2 = open_simulation(trained["scene"], fidelity="realtime", rom_model=trained["path"],
                           loaded_anatomy=trained["full"].anatomy)
    rom2.set_activations({"OOP": 1.0})
    with pytest.warns(rs.TrustWarning, match="contact penetration .* above the contact"):
        for k in range(1, 7):
            assert rom2.step(0.005 * k).converged
            if rom2.mode == "full":
                break
    assert rom2.mode == "full" and rom2.outputs()["rom_fallbacks"] == 1
    rom3 = open_simulation(trained["scene"], fidelity="realtime", rom_model=trained["path"],
                           loaded_anatomy=trained["full"].anatomy, trust="warn")
    rom3.set_activations({"OOP": 1.0})
    start = rom3.get_state()
    past = 0
    with warnings.catch_warnings(record=True) as seen:         # trust "warn": warned once,
        warnings.simplefilter("always")
        for k in range(1, 7):
            assert rom3.step(0.005 * k).converged and rom3.mode == "rom"
            past += rom3.stepper.penetration > rs.TOLERANCE
    assert [str(w.message).count("contact penetration") for w in seen] == [1]
    assert past >= 2 and rom3.trust_exceeded == {"penetration": past}   # every one counted
    import io
    state = rom3.get_state()               # part of the state, as the FMU serializes it
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in state.items()})
    with np.load(io.BytesIO(buf.getvalue()), allow_pickle=False) as z:
        restored = {k: z[k] for k in z.files}
    rom3.set_state(start)                  # a rollback undoes the count
    assert rom3.trust_exceeded == {}
    rom3.set_state(restored)
    assert rom3.trust_exceeded == {"penetration": past}


def test_the_lip_adapter_follows_candidate_pairs_the_term_replaced(trained):
    """After the full model re-picks the lip contact's candidate pairs (a fallback) and a
    reduced state is restored, the reduced lip contact works on the term's new pairs: the
    same force as the terms' own assemble() (the generic path) on them."""
    from solver.rom.contact import ReducedContact
    rom = open_simulation(trained["scene"], fidelity="realtime", rom_model=trained["path"],
                          loaded_anatomy=trained["full"].anatomy, trust="off")
    rom.set_activations({"OOP": 1.0})
    for k in range(1, 4):                                        # lips pressed
        assert rom.step(0.005 * k).converged
    c = rom.stepper.online.contact
    lip = next(a for a in c.adapters if hasattr(a, "passes"))
    term = lip.term
    for p in term.passes:                  # as the full model's follow_state: new arrays,
        ptr = p["ptr"]                     # here each slave's candidates in reverse order
        order = np.concatenate([np.arange(a, b)[::-1] for a, b in zip(ptr[:-1], ptr[1:])])
        free = p.get("pair_free")
        term._set_pairs(p, ptr.copy(), p["pair_tri"][order].copy(),
                        None if free is None else free[order].copy())
    q = rom.q
    fast = c.evaluate(q, False)[0].copy()
    assert all(w["src"] is w["p"]["pair_tri"] for w in lip.passes)   # rebuilt on them
    generic = ReducedContact(rom.op.contact, rom.op.V, rom.op.mesh.n_nodes, generic=True)
    ref = generic.evaluate(q, False)[0]
    assert np.abs(ref).max() > 0
    assert np.allclose(fast, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_realtime_without_a_trained_model_names_the_training_command(tmp_path,
                                                                     monkeypatch):
    from solver.rom import ModelNotTrained
    monkeypatch.setenv("FACEFMU_ROM_DIR", str(tmp_path))
    with pytest.raises(ModelNotTrained, match="benchmarks/rom_train.py"):
        open_simulation(Scene(driven=("OOP",)), fidelity="realtime")


def test_a_levels_own_rows_given_or_not_name_the_same_model():
    from solver.rom.store import model_key
    from solver.app.simulation import resolve_scene

    scene = resolve_scene("open_round").with_overrides(level="coarse", half=True)
    assert model_key(scene.with_overrides(rows=1)) == model_key(scene)
    assert model_key(scene.with_overrides(rows=2)) != model_key(scene)
    fine = scene.with_overrides(level="fine")
    assert model_key(fine.with_overrides(rows=2)) == model_key(fine)


def test_phrase_runs_are_valid_speech_like_patterns_and_reproducible():
    """solver.rom.train.random_phrase: increasing times within the run, activations in
    [0, 1], the jaw's opening within its range, more than one muscle taking part over each
    run of this seed (a gesture taking over from another), the same tasks from the same seed."""
    from solver.face.jaw import JAW_RANGES
    from solver.rom.train import snapshot_tasks
    scene = Scene(name="t", driven=("OOP", "RIS", "DLI", "LLSAN", "BUC", "ZYG"))
    tasks = snapshot_tasks(scene, 2, 0.15, 0.005, 1, jaw_runs=1, phrase_runs=12)
    phrases = [t for t in tasks if "phrase" in t["label"]]
    assert len(tasks) == 15 and len(phrases) == 12
    for i, t in enumerate(phrases):
        assert t["duration"] == 0.2
        names = [s.muscle for s in t["schedules"]]
        assert ("jaw_opening" in names) == (i % 3 == 2) == t["label"].startswith("jaw")
        assert len([m for m in names if m in scene.driven]) >= 2
        for s in t["schedules"]:
            assert s.times[0] == 0.0 and s.times[-1] == 0.2 and s.values[0] == 0.0
            assert np.all(np.diff(s.times) > 0)
            hi = JAW_RANGES["jaw_opening"][1] if s.muscle == "jaw_opening" else 1.0
            assert 0.0 <= min(s.values) and max(s.values) <= hi and max(s.values) > 0
    again = snapshot_tasks(scene, 2, 0.15, 0.005, 1, jaw_runs=1, phrase_runs=12)
    assert repr([t["schedules"] for t in again]) == repr([t["schedules"] for t in tasks])
    no_jaw = snapshot_tasks(scene, 2, 0.15, 0.005, 1, phrase_runs=3, jaw_phrase_runs=4)
    assert len(no_jaw) == 5          # no jaw phrases for a face without a jaw
    assert not any(s.muscle == "jaw_opening" for t in no_jaw for s in t["schedules"])


def test_phrase_runs_of_a_scene_driving_fewer_than_five_muscles():
    """A phrase's target takes one to five muscles: a scene driving fewer (open_round's
    four, or two) gets phrases over its own muscles, not an error."""
    from solver.rom.train import snapshot_tasks
    for driven in (("LLSAN", "RIS", "DLI", "OOP"), ("OOP", "RIS")):
        scene = Scene(name="t", driven=driven)
        tasks = snapshot_tasks(scene, 2, 0.15, 0.005, 1, jaw_runs=1, phrase_runs=12,
                               jaw_phrase_runs=3)
        phrases = [t for t in tasks if "phrase" in t["label"]]
        assert len(phrases) == 15
        used = set()
        for t in phrases:
            names = {s.muscle for s in t["schedules"]} - {"jaw_opening"}
            assert names and names <= set(driven)
            used |= names
        assert used == set(driven)


def test_jaw_phrase_runs_all_move_the_jaw_and_leave_the_other_runs_as_they_were():
    """jaw_phrase_runs: appended after the phrases from their own stream, each moving the
    jaw's opening within its range (label "jaw phrase k", k after the phrases' numbers),
    so that adding them keeps every earlier task (and its cached snapshots) unchanged."""
    from solver.face.jaw import JAW_RANGES
    from solver.rom.train import snapshot_tasks
    scene = Scene(name="t", driven=("OOP", "RIS", "DLI", "LLSAN", "BUC", "ZYG"))
    before = snapshot_tasks(scene, 2, 0.15, 0.005, 1, jaw_runs=1, phrase_runs=6)
    tasks = snapshot_tasks(scene, 2, 0.15, 0.005, 1, jaw_runs=1, phrase_runs=6,
                           jaw_phrase_runs=5)
    assert len(tasks) == len(before) + 5
    assert repr(tasks[:len(before)]) == repr(before)
    extra = tasks[len(before):]
    assert [t["label"] for t in extra] == [f"jaw phrase {6 + i}" for i in range(5)]
    for t in extra:
        jaw = [s for s in t["schedules"] if s.muscle == "jaw_opening"]
        assert len(jaw) == 1 and 0.0 < max(jaw[0].values) <= JAW_RANGES["jaw_opening"][1]
        assert any(s.muscle in scene.driven for s in t["schedules"])
    other = snapshot_tasks(scene, 2, 0.15, 0.005, 1, jaw_runs=1, phrase_runs=6,
                           jaw_phrase_runs=5, jaw_phrase_seed=12)
    assert repr(other[len(before):]) != repr(extra)
