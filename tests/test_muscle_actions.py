"""What single muscles and the paper's OOP + BUC case do to the lips (the paper's Figures 8
to 10), on the generic face (coarse, half) and on the reference face where present.

Static equilibria at a = 1 with the paper's whole-brick stiffening rule and lip/teeth contact (lip/lip contact is checked in the
transient test at the end: static Newton with pressed lips is not robust yet).
"""


import numpy as np
import pytest

from solver.face.anatomy.load import load_anatomy
from solver.app.scene import parse_scene
from solver.app.simulation import Simulation


CASES = {"RIS": {"RIS": 1.0}, "OOP": {"OOP": 1.0}, "BUC/2": {"BUC": 0.5}, "BUC": {"BUC": 1.0},
         "OOP+BUC": {"OOP": 1.0, "BUC": 1.0}}


def _static(anatomy, act):
    scene = parse_scene({"scene": {"analysis": "static"}, "muscles": {"driven": sorted(act)},
                         "effects": {"teeth_contact": True, "lip_contact": False,
                                     "stiffening_rule": "intersect"}})
    sim = Simulation(scene, loaded_anatomy=anatomy)
    rest = sim.outputs()
    sim.set_activations(act)
    stats = sim.step(1.0)
    assert stats.converged, stats.reason
    return sim, rest, sim.outputs()


@pytest.fixture(scope="module", params=["generic", "reference"])
def solved(request):
    if request.param == "generic":
        anatomy = load_anatomy("generic", "coarse", True)
    else:
        anatomy = load_anatomy(request.getfixturevalue("reference_face"), half=True)
    return anatomy, {name: _static(anatomy, act) for name, act in CASES.items()}


def test_ris_pulls_the_corners_laterally_and_back_and_widens_the_lips(solved):
    anatomy, res = solved
    sim, rest, out = res["RIS"]
    corner = anatomy.landmarks["corner_left"]
    x0 = anatomy.mesh.nodes[corner]
    u = sim.face.u[corner]
    assert abs(x0[0] + u[0]) > abs(x0[0]) + 0.05      # laterally (away from x = 0)
    assert u[1] < -0.05                                # back
    assert out["lip_width"] > rest["lip_width"] + 0.1


def test_oop_protrudes_the_lips_and_narrows_the_aperture(solved):
    _, res = solved
    _, rest, out = res["OOP"]
    assert out["lip_protrusion"] > 0.3
    assert out["lip_aperture"] < rest["lip_aperture"] - 0.1 or out["lip_aperture"] == 0.0


def test_oop_buc_closes_more_and_protrudes_less_than_oop_alone(solved):
    _, res = solved
    oop, both = res["OOP"][2], res["OOP+BUC"][2]
    assert both["lip_protrusion"] < oop["lip_protrusion"] - 0.2     # stiffened cheeks
    # the lips (nearly) close: within 0.5 mm statically, without lip/lip contact (the
    # reference face's rest aperture: 3.2 mm); with it they touch (the transient test below)
    assert both["lip_aperture"] <= min(oop["lip_aperture"] / 2, 0.5)


def _cheek_on_teeth(sim, cheek):
    """(total contact force (N) of the teeth on the cheek nodes (the nodes cheek (k,) among
    the teeth contact's slaves), their displacements along the contact's normal (mm,
    positive away from the teeth) where they touch)."""
    from solver.face.terms.contact import RigidContact
    force, along = 0.0, []
    for term in sim.contact:
        if not isinstance(term, RigidContact):
            continue
        on = np.isin(term.slaves, cheek)
        force += float(term.force[on].sum())
        f = term.nodal_force[term.slaves[on]]
        touch = np.linalg.norm(f, axis=1) > 0
        n = f[touch] / np.linalg.norm(f[touch], axis=1)[:, None]
        along.append((sim.face.u[term.slaves[on][touch]] * n).sum(axis=1))
    return force, np.concatenate(along) if along else np.zeros(0)


def _presses_cheek_on_teeth(anatomy, half, full):
    """The paper's observable for BUC (its Figure 9: the cheek "compressed against the
    teeth") from the static states at BUC 0.5 and 1 (Simulations): the teeth's contact
    force on the cheek nodes rises with the activation, and the touching cheek nodes have
    moved towards the teeth (along the contact normal). (holds, what was measured)"""
    cheek = np.unique(anatomy.mesh.bricks[full.face.regions["BUC"]])
    f_half, _ = _cheek_on_teeth(half, cheek)
    f_full, along = _cheek_on_teeth(full, cheek)
    # at rest the teeth push on nothing (the rest offsets: tests/test_contact.py)
    holds = (f_half > 0.01 and f_full > 1.2 * f_half and len(along) >= 3
             and np.mean(along) < 0)
    return holds, (f_half, f_full, along)


def test_buc_presses_the_cheek_against_the_teeth(solved):
    anatomy, res = solved
    holds, measured = _presses_cheek_on_teeth(anatomy, res["BUC/2"][0], res["BUC"][0])
    assert holds, measured


def test_the_cheek_check_fails_for_a_buc_without_force():
    """The check above can fail: BUC with a zero force scale (its stiffening alone) does
    not press the cheek on the teeth."""
    anatomy = load_anatomy("generic", "coarse", True)
    sims = []
    for a in (0.5, 1.0):
        scene = parse_scene({"scene": {"analysis": "static"},
                             "muscles": {"driven": ["BUC"], "force_scale": {"BUC": 0.0}},
                             "effects": {"teeth_contact": True, "lip_contact": False,
                                         "stiffening_rule": "intersect"}})
        sim = Simulation(scene, loaded_anatomy=anatomy)
        sim.set_activations({"BUC": a})
        assert sim.step(1.0).converged, sim.last.reason
        sims.append(sim)
    holds, (f_half, f_full, along) = _presses_cheek_on_teeth(anatomy, *sims)
    assert not holds and f_full == 0.0 and len(along) == 0


def _pressed_lips(duration):
    scene = parse_scene({"scene": {"analysis": "transient"},
                         "muscles": {"driven": ["BUC", "OOP"]},
                         "effects": {"teeth_contact": True, "lip_contact": True}})
    anatomy = load_anatomy("generic", "coarse", True)
    sim = Simulation(scene, loaded_anatomy=anatomy)
    worst = {t.name: 0.0 for t in sim.contact}
    for k in range(1, int(round(duration / 0.01)) + 1):
        sim.set_activations({"OOP": 1.0, "BUC": 1.0})
        stats = sim.step(0.01 * k)
        assert stats.converged, stats.reason
        for t in sim.contact:
            worst[t.name] = max(worst[t.name], t.max_penetration)
    return anatomy, sim, worst


def test_pressed_lips_close_without_interpenetrating():
    """OOP + BUC stepped to 1 for 0.3 s, transient with lip/lip and lip/teeth contact: the
    lips close; no active slave penetrates its master by more than 0.05 mm, and measured
    outside the model (solver.validation.stability.Probe: a lip-surface node inside another brick)
    no lip node has entered the other lip by more than 0.05 mm."""
    from solver.validation.stability import Probe
    anatomy, sim, worst = _pressed_lips(0.3)
    lips = next(t for t in sim.contact if t.name == "lip_contact")
    assert lips.n_active > 0 and lips.total_force > 0.01
    assert sim.outputs()["lip_aperture"] < 0.1
    assert max(worst.values()) < 0.05, worst
    assert Probe(anatomy).lip_overlap(sim.face.u) < 0.05


@pytest.mark.slow
def test_figures_8_to_10_under_the_paper_calibration_in_transient_analysis(reference_face):
    """The paper's Figures 8 to 10 under the `paper` calibration, on the reference face,
    as the paper ran them: transient, each activation ramped to 1 over 0.1 s and held to
    0.2 s, lip and teeth contact (static equilibria of OOP, BUC and OOP + BUC at these
    forces do not converge). RIS widens the mouth; OOP protrudes the lips and narrows the aperture;
    OOP + BUC protrudes less than OOP alone and closes the lips; BUC presses the cheek on
    the teeth, harder at a = 1 than at 0.5."""
    anatomy = load_anatomy(reference_face, half=True)
    res = {}
    for name, act in CASES.items():
        scene = parse_scene({"scene": {"analysis": "transient"},
                             "muscles": {"driven": sorted(act), "calibration": "paper"},
                             "effects": {"teeth_contact": True, "lip_contact": True,
                                         "stiffening_rule": "intersect"}})
        sim = Simulation(scene, loaded_anatomy=anatomy)
        rest = sim.outputs()
        for k in range(1, 21):
            sim.set_activations({m: a * min(1.0, k / 10) for m, a in act.items()})
            stats = sim.step(0.01 * k)
            assert stats.converged, (name, stats.reason)
        res[name] = (sim, rest, sim.outputs())
    sim, rest, out = res["RIS"]
    assert out["lip_width"] > rest["lip_width"] + 0.1
    _, rest, oop = res["OOP"]
    assert oop["lip_protrusion"] > 0.3
    assert oop["lip_aperture"] < rest["lip_aperture"] - 0.1 or oop["lip_aperture"] == 0.0
    both = res["OOP+BUC"][2]
    assert both["lip_protrusion"] < oop["lip_protrusion"] - 0.2
    assert both["lip_aperture"] <= min(oop["lip_aperture"] / 2, 0.5)
    cheek = np.unique(anatomy.mesh.bricks[res["BUC"][0].face.regions["BUC"]])
    f_half, _ = _cheek_on_teeth(res["BUC/2"][0], cheek)
    f_full, _ = _cheek_on_teeth(res["BUC"][0], cheek)
    assert f_half > 0.01 and f_full > 1.2 * f_half, (f_half, f_full)


def test_a_static_equilibrium_past_the_lip_fold_is_the_transient_steady_state():
    """OOP at 1 under the `paper` calibration, static, lip/lip and lip/teeth contact, on
    the generic face: load-stepped Newton stops at a limit point (the compressed lip
    ring folds) and the damped relaxation goes on to the equilibrium. That equilibrium is
    checked outside the static solver: the transient analysis of the same face and
    activation (inertia, the paper's Rayleigh damping), held for 0.8 s, settles at it
    (at a substep error tolerance of 1e-2 mm: the steady state does not depend on it)."""
    anatomy = load_anatomy("generic", "coarse", True)
    out = {}
    for analysis in ("static", "transient"):
        scene = parse_scene({"scene": {"analysis": analysis},
                             "muscles": {"driven": ["OOP"], "calibration": "paper"},
                             "effects": {"teeth_contact": True, "lip_contact": True},
                             "solver": {"substep_tol": 1e-2}})
        sim = Simulation(scene, loaded_anatomy=anatomy)
        sim.set_activations({"OOP": 1.0})
        if analysis == "static":
            res = sim.face.solve_static()
            assert res.converged, res.reason
            assert res.relaxation is not None and res.relaxation.converged
        else:
            for t in (0.1, 0.4, 0.8):
                assert sim.step(t).converged, sim.last.reason
        out[analysis] = sim.outputs()
    st, tr = out["static"], out["transient"]
    assert st["lip_protrusion"] > 1.0
    for key in ("lip_protrusion", "lip_width", "upper_lip_protrusion", "lower_lip_protrusion"):
        assert abs(st[key] - tr[key]) < 0.05, (key, st[key], tr[key])
