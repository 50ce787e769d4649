"""Structured brick meshes for tests and benchmarks."""

import numpy as np

from solver.core.mesh import Mesh


def box(nx, ny, nz, size=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), mapping=None):
    """A block of nx * ny * nz bricks; node sets 'xmin', 'xmax', 'ymin', ... on its faces.

    mapping: optional function (k, 3) reference-box points -> (k, 3) physical points,
    applied to the nodes (for distorted or curved blocks). Node sets refer to the faces
    of the reference box.
    """
    g = [np.linspace(o, o + s, n + 1) for o, s, n in zip(origin, size, (nx, ny, nz))]
    X, Y, Z = np.meshgrid(*g, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    nid = np.arange(len(pts)).reshape(nx + 1, ny + 1, nz + 1)
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    bricks = np.column_stack([
        nid[i, j, k], nid[i + 1, j, k], nid[i + 1, j + 1, k], nid[i, j + 1, k],
        nid[i, j, k + 1], nid[i + 1, j, k + 1], nid[i + 1, j + 1, k + 1], nid[i, j + 1, k + 1]])
    sets = {}
    for axis, name in enumerate("xyz"):
        c = pts[:, axis]
        lo, hi = origin[axis], origin[axis] + size[axis]
        sets[f"{name}min"] = np.flatnonzero(np.isclose(c, lo))
        sets[f"{name}max"] = np.flatnonzero(np.isclose(c, hi))
    if mapping is not None:
        pts = mapping(pts)
    return Mesh(pts, bricks, node_sets=sets)
