"""Static face responses on both anatomies: half face against full face, muscle effects."""


import pytest

from solver.face.anatomy.load import load_anatomy
from solver.face.face_model import FaceModel
from solver.face.anatomy.reference import reference_face_dir

REFERENCE = reference_face_dir()
# the reference face's case is slow (out of CI, whose run has the generic face's)
ANATOMIES = ["generic", pytest.param("reference", marks=[pytest.mark.slow, pytest.mark.skipif(
    not REFERENCE.is_dir(), reason=f"no reference face at {REFERENCE}")])]


def _spec(name):
    return "generic" if name == "generic" else REFERENCE


def _lips(name, half, activations):
    face = FaceModel(load_anatomy(_spec(name), "coarse", half), muscles=tuple(activations))
    face.set_activations(activations)
    res = face.solve_static()
    assert res.converged, res.reason
    return face.lip_outputs()


@pytest.mark.parametrize("name", ANATOMIES)
def test_half_face_matches_full_face_for_symmetric_activation(name):
    act = {"OOP": 0.5, "RIS": 0.5}
    half, full = _lips(name, True, act), _lips(name, False, act)
    rest = _lips(name, True, {})
    for key in ("lip_aperture", "lip_width", "upper_lip_protrusion", "lower_lip_protrusion"):
        change = abs(full[key] - rest[key])
        assert change > 1e-3, key                                    # the muscles did act
        assert abs(half[key] - full[key]) <= 0.01 * change, key        # 1 % of the motion
