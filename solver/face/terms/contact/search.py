"""Candidate search: the master triangles near each slave (k-d tree lists), distances from
points to a surface, and the tissue nodes near a rigid surface."""

import itertools

import numpy as np
from scipy.spatial import cKDTree

from solver.core.kernels.contact import nearest


def candidate_lists(tree, x, r):
    """CSR lists (ptr (s + 1,), ids) of the tree's points within r (scalar or (s,)) of
    the points x (s, 3)."""
    lists = tree.query_ball_point(x, r)
    ptr = np.zeros(len(x) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(c) for c in lists])
    return ptr, np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64,
                            count=ptr[-1])


def nearest_lists(xv, tris, x):
    """Candidate lists (ptr, triangles) of points x (s, 3) that hold each point's nearest
    triangle: the centroids within (distance to the nearest centroid + reach)."""
    cen = xv[tris].mean(axis=1)
    reach = np.linalg.norm(xv[tris] - cen[:, None], axis=2).max()
    tree = cKDTree(cen)
    return candidate_lists(tree, x, tree.query(x)[0] + reach + 1e-9)


def surface_distance(points, surface):
    """(k,) unsigned distance of points (k, 3) to a RigidSurface."""
    tris = np.ascontiguousarray(surface.triangles, dtype=np.int64)
    xv = np.ascontiguousarray(surface.vertices, dtype=np.float64)
    x = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    ptr, cand = nearest_lists(xv, tris, x)
    w, wt = np.empty(3), np.empty(3)
    return np.sqrt([nearest(p, xv, tris, cand[a:b], w, wt)[2]
                    for p, a, b in zip(x, ptr[:-1], ptr[1:])])


def nodes_near(mesh, nodes, surface, distance):
    """The node ids (k,) among nodes whose rest distance to surface is <= distance (mm)."""
    nodes = np.asarray(nodes, dtype=np.int64)
    return nodes[surface_distance(mesh.nodes[nodes], surface) <= distance]


def facing_areas(mesh, nodes, xv, tris, fn):
    """(s,) areas of nodes projected on the rigid surface: each boundary face of the mesh
    shares its area, projected on the normal fn of the surface triangle nearest to it
    (zero where it does not face the surface), equally among its corners."""
    faces = mesh.boundary_faces()
    faces = faces[np.isin(faces, nodes).any(axis=1)]
    x = mesh.nodes
    a = 0.5 * np.cross(x[faces[:, 2]] - x[faces[:, 0]], x[faces[:, 3]] - x[faces[:, 1]])
    cen = x[faces].mean(axis=1)
    ptr, cand = nearest_lists(xv, tris, cen)
    w, wt = np.empty(3), np.empty(3)
    t = np.array([cand[lo + nearest(c, xv, tris, cand[lo:hi], w, wt)[0]]
                  for c, lo, hi in zip(cen, ptr[:-1], ptr[1:])], dtype=np.int64)
    share = np.maximum(0.0, -(a * fn[t]).sum(axis=1)) / 4.0
    return np.bincount(faces.ravel(), np.repeat(share, 4), minlength=mesh.n_nodes)[nodes]


def tissue_points(mesh, nodes):
    """(s, 3) the mean centroid of the bricks around each node: a point on its tissue side."""
    cen = np.repeat(mesh.nodes[mesh.bricks].mean(axis=1), 8, axis=0)
    acc = np.zeros((mesh.n_nodes, 3))
    np.add.at(acc, mesh.bricks.ravel(), cen)
    count = np.bincount(mesh.bricks.ravel(), minlength=mesh.n_nodes)
    return acc[nodes] / count[nodes, None]
