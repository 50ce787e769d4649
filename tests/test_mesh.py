"""Mesh checks: bad bricks are rejected at load, naming them."""

import numpy as np
import pytest

import solver
from solver.core.meshgen import box


def test_box_counts_and_sets():
    m = box(3, 2, 4, (3.0, 2.0, 4.0))
    assert m.n_bricks == 24 and m.n_nodes == 4 * 3 * 5
    assert np.allclose(m.volumes, 1.0)
    assert len(m.node_sets["zmax"]) == 12
    assert len(m.boundary_faces()) == 2 * (3 * 2 + 2 * 4 + 3 * 4)


def test_inverted_brick_is_named():
    m = box(2, 1, 1)
    bricks = m.bricks.copy()
    bricks[1] = bricks[1][[4, 5, 6, 7, 0, 1, 2, 3]]            # upside down
    with pytest.raises(solver.MeshError, match="brick 1 is inverted"):
        solver.Mesh(m.nodes, bricks)


def test_zero_volume_brick_is_named():
    m = box(1, 1, 1)
    nodes = m.nodes.copy()
    nodes[m.node_sets["zmax"], 2] = 0.0                         # flattened
    with pytest.raises(solver.MeshError, match="brick 0 is of zero volume"):
        solver.Mesh(nodes, m.bricks, element_ids=np.array([0]))


def test_element_ids_from_a_file_are_used_in_messages():
    m = box(1, 1, 1)
    with pytest.raises(solver.MeshError, match="brick 4711"):
        solver.Mesh(m.nodes, m.bricks[:, [4, 5, 6, 7, 0, 1, 2, 3]], element_ids=np.array([4711]))


def test_out_of_range_node_id_and_bad_shapes():
    m = box(1, 1, 1)
    with pytest.raises(solver.MeshError, match="node index 99"):
        solver.Mesh(m.nodes, np.where(m.bricks == 7, 99, m.bricks))
    with pytest.raises(solver.MeshError, match=r"\(m, 8\)"):
        solver.Mesh(m.nodes, m.bricks[:, :6])
    nodes = m.nodes.copy()
    nodes[3, 1] = np.nan
    with pytest.raises(solver.MeshError, match="node 3"):
        solver.Mesh(nodes, m.bricks)


def test_wedge_is_accepted_and_flagged():
    m = box(1, 1, 1)
    wedge = m.bricks[0][[0, 1, 2, 2, 4, 5, 6, 6]]
    w = solver.Mesh(m.nodes, wedge[None])
    assert w.is_wedge.tolist() == [True]
    assert w.volumes[0] == pytest.approx(0.5)
