"""Scenes: validation errors, only the called-for terms, effects off = parameters zero."""

import numpy as np
import pytest

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.app.scene import SceneError, load_scene, parse_scene
from solver.app.simulation import Simulation, builtin_scenes, resolve_scene


@pytest.mark.parametrize("name", builtin_scenes())
def test_builtin_scenes_parse(name):
    scene = resolve_scene(name)
    assert scene.name == name and scene.duration > 0
    assert set(scene.activations(scene.duration)) == set(scene.driven)


def test_static_scene_builds_no_mass_or_damping_and_undriven_muscles_no_cables():
    sim = Simulation("paper_ris")
    assert sim.term_names == ["elasticity", "cables", "stiffening"]
    assert sim.integrator is None
    assert {MUSCLE_NAMES[m] for m in sim.face.cables.muscle} == {"RIS"}
    assert set(sim.face.stiffening.regions) == {"RIS"}
    sim.set_activations({"RIS": 0.3})
    assert sim.step(1.0).converged
    with pytest.raises(ValueError, match="OOP is not driven"):
        sim.set_activations({"OOP": 0.5})


def test_transient_scene_builds_what_it_asks_for():
    sim = Simulation(parse_scene({"muscles": {"driven": ["OOP"]},
                                  "effects": {"damping": False, "stiffening": False,
                                              "lip_contact": False, "teeth_contact": False}}))
    assert sim.term_names == ["elasticity", "cables", "inertia"]


def test_the_default_is_the_papers_model_for_speech():
    """Simulation() and a scene file that names no effect: all ten muscles, stiffening,
    inertia, Rayleigh damping (alpha 40 1/s, beta 0.03 s), lip/lip and lip/teeth contact."""
    for scene in (Simulation().scene, parse_scene({})):
        assert scene.driven == MUSCLE_NAMES
        assert scene.effects == ["elasticity", "cables", "stiffening", "inertia", "damping",
                                 "lip_contact", "teeth_contact"]
        assert (scene.alpha, scene.beta) == (40.0, 0.03)
        assert scene.contact_warnings() == []
    sim = Simulation()
    assert {"upper_teeth+lower_teeth_contact", "lip_contact", "inertia", "damping"} <= set(
        sim.term_names)
    assert resolve_scene("no_contact").contact_warnings() == [
        "scene 'no_contact' leaves out lip/lip and lip/teeth contact: lips and teeth can "
        "interpenetrate"]


EFFECT_KEYS = ("inertia", "damping", "stiffening", "stiffening_rule", "lip_contact",
               "teeth_contact", "gravity")


@pytest.mark.parametrize("name", builtin_scenes())
def test_every_builtin_scene_states_its_effects(name):
    import tomllib

    from solver.app.simulation import BUILTIN_DIR
    data = tomllib.loads((BUILTIN_DIR / f"{name}.toml").read_text())
    assert set(EFFECT_KEYS) <= set(data.get("effects", {})), name


@pytest.mark.parametrize("text,key", [
    ('[effects]\ninertia = "yes"\n', "effects.inertia"),
    ('[effects]\nfriction = true\n', "effects.friction"),
    ('[efects]\n', "efects"),
    ('[scene]\nanalysis = "dynamic"\n', "scene.analysis"),
    ('[anatomy]\nlevel = "ultra"\n', "anatomy.level"),
    ('[muscles]\ndriven = ["OOP", "XYZ"]\n', "muscles.driven"),
    ('[solver]\nmax_substep = -1.0\n', "solver.max_substep"),
    ('[solver]\nintegrator = "rk4"\n', "solver.integrator"),
    ('[solver]\nsubstep_rtol = -0.1\n', "solver.substep_rtol"),
    ('[[schedule]]\nmuscle = "OOP"\nkind = "ramp"\nstart = 0.2\nend = 0.1\nto = 1.0\n',
     "schedule.0"),
    ('[[schedule]]\nmuscle = "OOP"\nkind = "step"\ntime = 0.1\nvalue = 2.0\n', "schedule.0"),
    ('[[schedule]]\nmuscle = "OOP"\nkind = "step"\nvalue = 1.0\n', "schedule.0.time"),
    ('[scene\n', ""),
])
def test_bad_scene_files_are_refused_naming_file_and_key(tmp_path, text, key):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(path) in str(info.value) and f"[{key}]" in str(info.value)


def test_missing_scene_file_is_named(tmp_path):
    with pytest.raises(SceneError, match="nowhere.toml"):
        resolve_scene(str(tmp_path / "nowhere.toml"))


def _short_run(**effects):
    scene = parse_scene({"muscles": {"driven": ["OOP"]}, **effects,
                         "scene": {"duration": 0.005},
                         "outputs": {"interval": 0.005, "record": ["lip_protrusion"]},
                         "schedule": [{"muscle": "OOP", "kind": "step", "time": 0.0,
                                       "value": 0.8}]})
    sim = Simulation(scene)
    sim.run()
    return sim.face.u.copy(), sim.term_names


def test_damping_off_equals_zero_damping_parameters():
    u_off, terms_off = _short_run(effects={"damping": False})
    u_zero, terms_zero = _short_run(damping={"alpha": 0.0, "beta": 0.0})
    assert "damping" not in terms_off and "damping" not in terms_zero
    assert np.abs(u_off).max() > 1e-3
    assert np.allclose(u_off, u_zero, rtol=0, atol=1e-12)


def test_gravity_off_equals_zero_gravity():
    u_off, terms_off = _short_run()
    u_zero, terms_zero = _short_run(effects={"gravity": "upright"}, gravity={"g": 0.0})
    u_on, _ = _short_run(effects={"gravity": "upright"})
    assert "gravity" not in terms_off and "gravity" in terms_zero
    assert np.allclose(u_off, u_zero, rtol=0, atol=1e-10)
    assert np.abs(u_on - u_off).max() > 1e-3               # gravity itself does something
