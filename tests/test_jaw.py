"""The jaw (solver.face.jaw): rigid kinematics, what it carries, the lips it opens, tangents.

The checks: the closed jaw is exactly the model without one; the mandible's nodes, the
lower teeth and the mandible's insertions follow the rigid motion computed here from
scratch; 12 mm of incisor opening opens the lips by more than 6 mm on both faces with no
lip node behind the lower teeth (the stability Probe, outside the model); the tangents of
the terms the jaw moves against finite differences; refusals leave the state as it was.
"""

import copy
import math

import numpy as np
import pytest

from solver.face.anatomy.load import load_anatomy
from solver.core.errors import ParameterError
from solver.face.jaw import BALKWILL_DEG, BONWILL_MM, JAW_RANGES
from solver.app.simulation import Simulation
from solver.validation.stability import CONTACT_TOLERANCE, Probe
from solver.face.anatomy.reference import reference_face
from test_contact import Runner, fd_derivatives, fd_errors

REFERENCE_FACE = reference_face()


def _rigid(x, centre, theta_deg, p):
    """x (k, 3) turned by -theta about the x axis through centre, then moved p along y."""
    t = math.radians(theta_deg)
    R = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(t), math.sin(t)],
                  [0.0, -math.sin(t), math.cos(t)]])
    return (x - centre) @ R.T + centre + np.array([0.0, p, 0.0])


def _without_jaw(anatomy):
    """A copy of the anatomy without the 'fixed_mandible' set: a model with no jaw."""
    out = copy.copy(anatomy)
    out.mesh = copy.copy(anatomy.mesh)
    out.mesh.node_sets = {k: v for k, v in anatomy.mesh.node_sets.items()
                          if k != "fixed_mandible"}
    return out


def test_the_closed_jaw_is_the_model_without_one():
    """With the jaw set to 0 at every step, the lip outputs and displacements equal those
    of the same model built without a jaw to 1e-9 mm (they are identical)."""
    with_jaw = Simulation("default")
    plain = Simulation("default", loaded_anatomy=_without_jaw(with_jaw.anatomy))
    assert with_jaw.face.jaw is not None and plain.face.jaw is None
    for sim in (with_jaw, plain):
        sim.set_activations({"OOP": 0.8, "RIS": 0.4, "DLI": 0.5})
    for _ in range(3):
        with_jaw.set_jaw(0.0, 0.0)
        for sim in (with_jaw, plain):
            assert sim.step(sim.t + 0.01).converged
    a, b = with_jaw.outputs(), plain.outputs()
    assert np.abs(with_jaw.face.u - plain.face.u).max() <= 1e-9
    for k in ("lip_aperture", "lip_protrusion", "lip_width", "contact_force"):
        assert abs(a[k] - b[k]) <= 1e-9, k
    assert a["incisor_opening"] == 0.0 and a["lip_protrusion"] > 0.05


def test_axis_placement_follows_the_bonwill_triangle_and_the_balkwill_angle():
    sim = Simulation("default")
    g = sim.face.jaw.geometry
    r = g.incisor - g.centre
    assert np.linalg.norm(r) == pytest.approx(BONWILL_MM) and BONWILL_MM == \
        pytest.approx(math.sqrt(100.0 ** 2 - 50.0 ** 2))
    assert math.degrees(math.atan2(-r[2], r[1])) == pytest.approx(BALKWILL_DEG)
    assert r[0] == 0.0 and g.incisor[0] == 0.0
    # the incisor point lies between the teeth surfaces' mid-line edges
    up, low = (sim.anatomy.rigid_surfaces[k].vertices for k in ("upper_teeth", "lower_teeth"))
    assert low[:, 2].min() < g.incisor[2] < up[:, 2].max()


@pytest.mark.parametrize("pose", [(10.0, 0.0), (6.0, 2.5), (0.0, -1.0)])
def test_the_mandible_and_the_lower_teeth_follow_the_rigid_motion(pose):
    """All muscles at 0: the mandible's nodes and the lower teeth's vertices are where
    the rigid motion (computed here) puts them, the upper teeth where they were; the
    incisor opening is the distance the motion moves the incisor point."""
    sim = Simulation("default", driven=())
    g = sim.face.jaw.geometry
    sim.set_jaw(*pose)
    assert sim.step(0.02).converged
    X = sim.anatomy.mesh.nodes[g.nodes]
    expected = _rigid(X, g.centre, *pose) - X
    assert np.abs(sim.face.u[g.nodes] - expected).max() < 1e-12
    assert sim.jaw == pose
    moved = _rigid(g.incisor[None], g.centre, *pose)[0]
    assert sim.outputs()["incisor_opening"] == pytest.approx(np.linalg.norm(moved - g.incisor),
                                                             abs=1e-12)
    if pose[1] == 0.0:
        chord = 2.0 * BONWILL_MM * math.sin(math.radians(pose[0]) / 2.0)
        assert sim.outputs()["incisor_opening"] == pytest.approx(chord, rel=1e-12)
    teeth = next(t for t in sim.contact if getattr(t, "motion", None))
    moving = teeth.motion[1]
    assert 0 < moving.sum() < len(moving)
    assert np.abs(teeth.vertices[moving] - _rigid(teeth.rest_vertices[moving], g.centre, *pose)
                  ).max() < 1e-12
    assert np.array_equal(teeth.vertices[~moving], teeth.rest_vertices[~moving])
    # the normals move_to refreshed (those the motion changes) are a whole update's
    from solver.face.terms.contact.surfaces import Normals
    whole = Normals(teeth.tris, len(teeth.vertices)).update(teeth.vertices)
    for a, b in zip(teeth.normals.args()[:3], whole.args()[:3]):
        assert np.array_equal(a, b)


def test_the_mandible_insertions_move_and_the_others_stay():
    sim = Simulation("default", lip_contact=False, teeth_contact=False)
    cab, g = sim.face.cables, sim.face.jaw.geometry
    muscles = np.array([m for m in cab.muscle])
    sim.face.set_jaw_state((8.0, 1.0))
    X = cab.rest_points(1.0)
    names = np.array(["LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP",
                      "OOM"])[muscles]
    on = cab.jaw_ends
    assert on.any() and set(names[on.any(axis=1)]) <= {"DAO", "DLI", "MENT"}
    assert np.abs(X[on] - _rigid(cab.X[on], g.centre, 8.0, 1.0)).max() < 1e-12
    assert np.array_equal(X[~on], cab.X[~on])


def _opening_case(sim):
    """Open the jaw to 12 mm of incisor opening over 0.1 s with OOP at 0.2; returns the
    aperture at rest and after, and the Probe's deepest teeth and lip penetrations."""
    g = sim.face.jaw.geometry
    theta = 2.0 * math.degrees(math.asin(6.0 / BONWILL_MM))
    probe = Probe(sim.anatomy, jaw=sim.face.jaw)
    rest = sim.outputs()["lip_aperture"]
    worst = [0.0, 0.0]
    sim.set_activations({"OOP": 0.2})
    for k in range(1, 11):
        sim.set_jaw(opening=theta * min(1.0, k / 5))
        stats = sim.step(0.01 * k)
        assert stats.converged, stats.reason
        lips, teeth = probe.penetrations(sim.face.u)
        worst = [max(worst[0], lips), max(worst[1], teeth)]
    assert sim.outputs()["incisor_opening"] == pytest.approx(12.0, abs=1e-9)
    assert g.incisor_opening(sim.face.jaw.start) == pytest.approx(12.0, abs=1e-9)
    return rest, sim.outputs()["lip_aperture"], worst


def test_twelve_mm_of_incisor_opening_opens_the_generic_lips_by_six_mm():
    rest, opened, (lips, teeth) = _opening_case(Simulation("default", fidelity="balanced"))
    assert opened - rest >= 6.0, (rest, opened)
    assert teeth <= CONTACT_TOLERANCE and lips <= CONTACT_TOLERANCE


@pytest.mark.slow                   # the generic face's twin runs in CI; examples/jaw_pictures.py
@pytest.mark.skipif(REFERENCE_FACE is None, reason="reference face data absent")
def test_twelve_mm_of_incisor_opening_opens_the_reference_lips_by_six_mm():
    sim = Simulation("default", fidelity="balanced", anatomy=str(REFERENCE_FACE))
    rest, opened, (lips, teeth) = _opening_case(sim)
    assert opened - rest >= 6.0, (rest, opened)
    assert teeth <= CONTACT_TOLERANCE


def _pressed_state(pose):
    """The default scene with the lips on the teeth (OOP at 1) and the jaw at pose."""
    sim = Simulation("default")
    sim.set_activations({"OOP": 1.0, "DLI": 0.5, "MENT": 0.5, "DAO": 0.5})
    sim.set_jaw(*pose)
    for k in range(1, 4):
        assert sim.step(0.01 * k).converged
    return sim


def _smooth_fd_errors(term, u):
    """fd_errors over the DOFs where the term's force is differentiable: a DOF whose
    central differences at h = 1e-6 and 1e-7 disagree crosses a jump within h (a node
    behind the teeth on the medial axis of their crease, whose nearest face changes) and
    is left out. Returns (tangent error, residual error, the fraction left out)."""
    run = Runner(term, len(u))
    asm = run(u)
    K, r = asm.matrix().toarray(), asm.residual
    K1, r1 = fd_derivatives(run, u, K, r, 1e-6)
    K2, _ = fd_derivatives(run, u, K, r, 1e-7)
    cols = np.flatnonzero(np.abs(K).sum(axis=0) + np.abs(r) > 0)
    jump = np.abs(K1 - K2).max(axis=0) > 1e-3 * np.abs(K).max()
    keep = np.setdiff1d(cols, np.flatnonzero(jump))
    rows = keep[:, None]
    return (np.abs(K - K1)[rows, keep].max() / np.abs(K).max(),
            np.abs(r - r1)[keep].max() / np.abs(r).max(), 1.0 - len(keep) / len(cols))


def test_teeth_and_cable_tangents_at_an_open_jaw_match_finite_differences():
    sim = _pressed_state((6.0, 1.0))
    teeth = next(t for t in sim.contact if getattr(t, "motion", None))
    u = sim.face.u.copy()
    err_k, err_r, left_out = _smooth_fd_errors(teeth, u)
    assert teeth.n_active > 10 and np.any(teeth.pose != 0.0)
    assert left_out < 0.2 and err_k < 1e-5 and err_r < 1e-5, (err_k, err_r, left_out)
    cab = sim.face.cables
    assert cab.jaw_ends.any()
    err_k, err_r = fd_errors(cab, u)
    assert err_k < 1e-5 and err_r < 1e-5


def test_bad_jaw_values_are_refused_by_name_and_change_nothing():
    sim = Simulation("default", driven=())
    sim.set_jaw(5.0, 1.0)
    assert sim.step(0.01).converged
    state = sim.get_state()
    for kwargs, needle in (({"opening": float("nan")}, "jaw_opening = nan"),
                           ({"opening": 25.0}, "jaw_opening = 25.0"),
                           ({"opening": -0.5}, "jaw_opening = -0.5"),
                           ({"protrusion": float("inf")}, "jaw_protrusion = inf"),
                           ({"opening": 3.0, "protrusion": 12.0}, "jaw_protrusion = 12.0")):
        with pytest.raises(ParameterError, match=needle.replace(".", r"\.")):
            sim.set_jaw(**kwargs)
        assert np.array_equal(sim.face.jaw.target, [5.0, 1.0])
    assert sim.step(0.02).converged
    assert np.array_equal(sim.face.u, sim.face.u) and sim.jaw == (5.0, 1.0)
    sim.set_state(state)
    assert sim.jaw == (5.0, 1.0)
    assert JAW_RANGES["jaw_opening"] == (0.0, 20.0)


def test_a_failed_step_puts_the_jaw_back():
    """A step that cannot converge (max_cutbacks 0 and a 20 deg jump in one tiny step is
    not needed: a forced failure) leaves the jaw's pose and prescriptions at the last
    converged state."""
    sim = Simulation("default", driven=())
    sim.set_jaw(4.0)
    assert sim.step(0.01).converged
    u0 = sim.face.u.copy()
    sim.integrator.max_cutbacks = 0
    sim.integrator.min_substep = sim.integrator.max_substep = 1e-3
    original = sim.integrator._substep
    sim.integrator._substep = lambda *a, **k: (None, None, None, original(*a, **k)[3])
    sim.set_jaw(8.0)
    assert not sim.step(0.02).converged
    sim.integrator._substep = original
    assert sim.jaw == (4.0, 0.0) and np.array_equal(sim.face.jaw.target, [4.0, 0.0])
    assert np.array_equal(sim.face.u, u0)
    assert sim.step(0.02).converged and sim.jaw == (4.0, 0.0)


def test_a_scene_schedule_drives_the_jaw(tmp_path):
    from solver.app.scene import SceneError, load_scene
    path = tmp_path / "jaw.toml"
    path.write_text('[scene]\nname = "jaw"\nduration = 0.04\n'
                    '[effects]\nlip_contact = false\nteeth_contact = false\n'
                    '[outputs]\ninterval = 0.01\n'
                    '[[schedule]]\njaw = "opening"\nkind = "ramp"\nstart = 0.0\nend = 0.02\n'
                    'to = 6.0\n')
    rows = Simulation(load_scene(path), driven=()).run()
    assert [r["jaw_opening"] for r in rows] == pytest.approx([0.0, 3.0, 6.0, 6.0, 6.0])
    assert rows[-1]["incisor_opening"] == pytest.approx(
        2.0 * BONWILL_MM * math.sin(math.radians(3.0)))
    path.write_text('[[schedule]]\njaw = "opening"\nkind = "step"\ntime = 0.0\nvalue = 30.0\n')
    with pytest.raises(SceneError, match="schedule.0"):
        load_scene(path)


def test_the_moved_teeth_keep_every_slaves_nearest_triangle_among_its_candidates():
    """Opened by 12 mm, the lower arch's first row stretches over the gap (its vertices on
    the seam stay with the upper arch): each slave's candidate triangles must still hold
    its nearest triangle of the whole surface (the candidate search reaches as far as the
    stretched triangles are long)."""
    from solver.core.kernels.contact import nearest
    sim = Simulation("default", fidelity="balanced", driven=())
    theta = 2.0 * math.degrees(math.asin(6.0 / BONWILL_MM))
    for k in range(1, 6):
        sim.set_jaw(opening=theta * min(1.0, k / 5))
        assert sim.step(0.01 * k).converged
    teeth = next(t for t in sim.contact if getattr(t, "motion", None))
    x = teeth.x0 + sim.face.u[teeth.slaves]
    ptr, cand = teeth._candidates(x)
    everything = np.arange(len(teeth.tris))
    w, wt = np.empty(3), np.empty(3)
    for i, p in enumerate(x):
        near = nearest(p, teeth.vertices, teeth.tris, cand[ptr[i]:ptr[i + 1]], w, wt)[2]
        best = nearest(p, teeth.vertices, teeth.tris, everything, w, wt)[2]
        assert near <= best + 1e-12, (i, near, best)
