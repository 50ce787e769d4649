"""Lip aperture as the smallest mid-sagittal distance between the lip contours."""

import numpy as np
import pytest

from solver.face.anatomy.load import load_anatomy
from solver.face.aperture import contour_gap, midsagittal_edges
from solver.face.face_model import FaceModel


def _gap(upper_pts, lower_pts):
    yz = np.array(upper_pts + lower_pts, dtype=float)
    nu = len(upper_pts)
    up = np.array([(i, i + 1) for i in range(nu - 1)])
    lo = np.array([(i, i + 1) for i in range(nu, len(yz) - 1)])
    return contour_gap(yz, up, lo)


def test_parallel_lips_are_their_spacing_apart():
    assert _gap([(0, 1.0), (5, 1.0)], [(0, 0.0), (5, 0.0)]) == pytest.approx(1.0)


def test_the_gap_is_the_nearest_approach_not_a_vertical_one():
    # the upper lip's end hangs over the middle of the lower lip's segment
    assert _gap([(-5, 3.0), (2, 0.5)], [(0, 0.0), (5, 0.0)]) == pytest.approx(0.5)
    # lips slid past each other: edges 1 apart in z but 3 apart in y, faces 0.2 apart
    g = _gap([(0, 0.2), (3, 0.2), (6, 2.0)], [(-3, -1.0), (0, 0.0), (3, 0.0)])
    assert g == pytest.approx(0.2)


def test_crossing_lips_have_no_aperture():
    assert _gap([(0, 0.5), (5, -0.1)], [(0, 0.0), (5, 0.0)]) == 0.0


def test_midsagittal_edges_skip_wedge_repeats_and_off_plane_edges():
    faces = np.array([[0, 1, 2, 3], [1, 4, 4, 2]])
    edges = midsagittal_edges(faces, [0, 1, 4])
    assert edges.tolist() == [[0, 1], [1, 4]]


def test_generic_face_at_rest_shows_its_slit_gap():
    face = FaceModel(load_anatomy("generic", "coarse", True), muscles=())
    assert face.lip_outputs()["lip_aperture"] == pytest.approx(0.4, abs=1e-9)
    u = np.zeros_like(face.u)
    up = face.anatomy.mesh.node_sets["slit_upper"]
    u[up, 2] = -0.55                                   # the upper lip pushed through
    assert face.lip_outputs(u)["lip_aperture"] == 0.0
