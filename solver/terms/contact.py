r"""Frictionless penalty contact: lips on the rigid teeth, lip on lip.

Both terms are node-on-surface: a slave node x meets a triangulated master surface.

Gap. c is the closest point of the master surface to x (over a candidate set of
triangles; on a face, an edge or a vertex of a triangle), d = x - c, and

    g = -|d|  if (x - c) . N < 0,  else +|d|,

with N the pseudo-normal of the closest feature (the face's normal; on an edge the mean of
its two faces' normals; at a vertex the angle-weighted normal): the signed distance to the
surface, negative inside. The outward normal is n = d / g where g != 0 (n = face normal on
a face). An open sheet (the teeth) has free boundary edges: a node whose closest point lies
on one (or on a free boundary vertex) has no side and is out of contact: there is no
contact beyond the sheet's edge, a lip may wrap around the incisors.

Energy, force, tangent (per slave node i, stiffness k_i = penalty * A_i, A_i its
tributary area, penalty in N/mm^3):

    Psi_i = 1/2 k_i g^2 = k_i F,  F = 1/2 |d|^2          where g < 0 (else 0),
    dPsi/dx = k_i d = k_i g n     (the contact force on the node is -k_i d = k_i |g| n),
    d2Psi/dx dx = k_i (I - dc/dx) = k_i n n on a face, k_i (I - t t) on an edge (unit
    edge direction t), k_i I at a vertex.

On a face, where the normal of a rigid facet does not rotate, the tangent is k n n; on
edges and vertices the closest point moves and the full I - dc/dx is kept. For a
deformable master triangle (x_1, x_2, x_3) the same F is differentiated over all four
nodes with the envelope theorem (solver.kernels.contact): dF/dX_a = N_a d,
N = (1, -w_1, -w_2, -w_3) (w: barycentric weights of c), and the Hessian
N N^T (x) I - B M^-1 B^T carries the rotation of the master's normal and the sliding of
c exactly. Psi is C1 across g = 0 and across feature changes, so Newton with the line
search converges; the tangent is the exact Hessian for a fixed active set (checked by
finite differences in tests/test_contact.py).

Penalty choice. A node carrying a force f penetrates by f / (penalty * A). With the
default penalty = 10 N/mm^3 and lip-node areas of 2 - 7 mm^2 (the reference face's lip
surfaces), one node takes 1 N at 0.015 - 0.05 mm: a total lip force of 1 N, shared by
several nodes, stays well below 0.05 mm. This is about 2000 times the tissue's shear
modulus per mm (mu = 5 kPa) and 4 times its bulk modulus per mm of a lip element (2.5 MPa
over 2.6 mm), and Newton (a direct solver, a residual line search) converges in a few
iterations over the active-set changes, so pure penalty is used: no augmented-Lagrangian
update, whose one update per load step would not converge the multipliers anyway.

RigidContact: node-on-rigid-surface (lips and cheeks on the teeth). The sheet (an open
surface, any triangle orientation) is oriented towards the tissue: by the side on which
most slaves' tissue lies at rest (the mean centroid of each slave's bricks, which is off
the surface even where the slave touches it); slave nodes behind the oriented sheet at
rest by more than rest_tolerance are dropped (ids in .dropped). Search: a cKDTree of the triangle centroids; each slave keeps the
triangles whose centroid is within search_radius + (largest centroid-vertex distance) +
margin of its position when the list was made, refreshed once a slave has moved by more
than margin. So every triangle within search_radius of a slave is a candidate, and
penetrations deeper than search_radius are not seen.

LipContact: two passes of node-on-surface (upper-lip nodes on the lower lip's triangles
and the reverse; quads split into two triangles). The sparsity pattern is built once, so
the candidate (slave node, master triangle) pairs are fixed at rest: master triangles
within radius of the slave, facing it (slave's area-weighted normal . triangle normal < 0,
which keeps the back and the filled caps of a closed lip surface out), at most max_pairs
nearest per slave. Nodes on both surfaces (the joined mouth corners) are no slaves, and a
slave inside the other lip at rest is dropped. Each slave takes its nearest candidate;
penetrations deeper than depth are ignored (a node that came in elsewhere than through its
candidates). Inactive pairs scatter zeros.

After each assembly both terms hold: gap (s,) signed gaps of their slaves (inf: no
candidate or a free boundary), n_active, max_penetration (mm, >= 0), total_force (N, the
sum of the slaves' normal force magnitudes k_i |g_i|) and nodal_force (n, 3): the contact
force on every mesh node (on the slaves and, for LipContact, on the master nodes).
"""

import numpy as np
from scipy.spatial import cKDTree

from ..errors import ParameterError
from ..kernels.contact import (nearest, pair_distances, rigid_contact, surface_contact,
                               surface_normals)
from .base import Term

PENALTY = 10.0             # N/mm^3: contact pressure per mm of penetration


def triangulate(faces):
    """(f, 3) or (f, 4) faces -> (t, 3) triangles (quads split along their 0-2 diagonal;
    triangles with a repeated node, from degenerate quads, are left out)."""
    faces = np.asarray(faces, dtype=np.int64)
    tris = faces if faces.shape[1] == 3 else np.vstack([faces[:, [0, 1, 2]],
                                                        faces[:, [0, 2, 3]]])
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 2] != tris[:, 0])
    return np.ascontiguousarray(tris[keep])


def tributary_areas(x, tris, n):
    """(n,) a third of the area of the triangles tris (t, 3) over points x at each vertex."""
    a = 0.5 * np.linalg.norm(np.cross(x[tris[:, 1]] - x[tris[:, 0]],
                                      x[tris[:, 2]] - x[tris[:, 0]]), axis=1)
    return np.bincount(tris.ravel(), np.repeat(a / 3.0, 3), minlength=n)


class _Topology:
    """Edge neighbours of triangles tris (t, 3) over p points: nbr (t, 3) the triangle
    across edge j = (j, j + 1 mod 3) or -1, free_edge (t, 3), free_vertex (p,)."""

    def __init__(self, tris, p):
        t = len(tris)
        e = np.sort(np.stack([tris, np.roll(tris, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        _, inv, count = np.unique(e, axis=0, return_inverse=True, return_counts=True)
        inv = inv.ravel()
        if count.max(initial=0) > 2:
            raise ParameterError("a contact surface has an edge shared by more than two "
                                 "triangles")
        order = np.argsort(inv, kind="stable")
        twin = np.flatnonzero(np.diff(inv[order]) == 0)
        a, b = order[twin], order[twin + 1]
        nbr = -np.ones(3 * t, dtype=np.int64)
        nbr[a], nbr[b] = b // 3, a // 3
        self.nbr = nbr.reshape(t, 3)
        self.free_edge = self.nbr < 0
        self.free_vertex = np.zeros(p, dtype=bool)
        fe = np.stack([tris, np.roll(tris, -1, axis=1)], axis=2)[self.free_edge]
        self.free_vertex[fe.ravel()] = True


class _Normals:
    """Face, edge and vertex (pseudo-)normals of a triangle surface, refreshed by update."""

    def __init__(self, tris, p):
        self.tris = tris
        self.topo = _Topology(tris, p)
        self.fn = np.empty((len(tris), 3))
        self.en = np.empty((len(tris), 3, 3))
        self.vn = np.empty((p, 3))

    def update(self, x):
        surface_normals(x, self.tris, self.topo.nbr, self.fn, self.en, self.vn)
        return self

    def args(self):
        """The kernels' (fn, en, vn, free_edge, free_vertex)."""
        return self.fn, self.en, self.vn, self.topo.free_edge, self.topo.free_vertex


def _lists(tree, x, r):
    """CSR candidate lists (ptr (s + 1,), ids) of the tree's points within r (or (s,)) of
    the points x (s, 3)."""
    lists = tree.query_ball_point(x, r)
    ptr = np.zeros(len(x) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(c) for c in lists])
    return ptr, np.fromiter((t for c in lists for t in c), dtype=np.int64, count=ptr[-1])


def _nearest_lists(xv, tris, x):
    """Candidate lists (ptr, triangles) of points x (s, 3) that hold each point's nearest
    triangle: centroids within (distance to the nearest centroid + reach)."""
    cen = xv[tris].mean(axis=1)
    reach = np.linalg.norm(xv[tris] - cen[:, None], axis=2).max()
    tree = cKDTree(cen)
    return _lists(tree, x, tree.query(x)[0] + reach + 1e-9)


def surface_distance(points, surface):
    """(k,) unsigned distance of points (k, 3) to a RigidSurface."""
    tris = np.ascontiguousarray(surface.triangles, dtype=np.int64)
    xv = np.ascontiguousarray(surface.vertices, dtype=np.float64)
    x = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    ptr, cand = _nearest_lists(xv, tris, x)
    w = np.empty(3)
    return np.sqrt([nearest(p, xv, tris, cand[a:b], w)[2]
                    for p, a, b in zip(x, ptr[:-1], ptr[1:])])


def nodes_near(mesh, nodes, surface, distance):
    """The nodes (k,) among node ids nodes whose rest distance to surface is <= distance."""
    nodes = np.asarray(nodes, dtype=np.int64)
    return nodes[surface_distance(mesh.nodes[nodes], surface) <= distance]


def _boundary_areas(mesh, nodes):
    """(s,) tributary area of nodes on the mesh's boundary faces; refuses inner nodes."""
    area = tributary_areas(mesh.nodes, triangulate(mesh.boundary_faces()), mesh.n_nodes)[nodes]
    if (area <= 0).any():
        raise ParameterError(f"slave node {mesh.node_ids[nodes[np.argmax(area <= 0)]]} is "
                             "not on the mesh's boundary (give area= explicitly)")
    return area


def _tissue_points(mesh, nodes):
    """(s, 3) the mean centroid of the bricks around each node: a point on its tissue side."""
    cen = np.repeat(mesh.nodes[mesh.bricks].mean(axis=1), 8, axis=0)
    acc = np.zeros((mesh.n_nodes, 3))
    np.add.at(acc, mesh.bricks.ravel(), cen)
    count = np.bincount(mesh.bricks.ravel(), minlength=mesh.n_nodes)
    return acc[nodes] / count[nodes, None]


class _Report:
    """Contact measures of the last assembly (see the module docstring)."""

    def _report(self, gap, k, nodal_force):
        act = gap < 0
        self.gap = gap
        self.n_active = int(act.sum())
        self.max_penetration = float(-gap[act].min()) if self.n_active else 0.0
        self.total_force = float((k[act] * -gap[act]).sum())
        self.nodal_force = nodal_force


class RigidContact(Term, _Report):
    """Frictionless penalty contact of slave nodes on a rigid triangulated surface.

    mesh            solver.Mesh
    slave_nodes     (s,) node ids that may touch (e.g. lip nodes near the teeth)
    surface         solver.anatomy.RigidSurface (vertices (p, 3), triangles (t, 3))
    penalty         N/mm^3; node stiffness k_i = penalty * area_i (N/mm)
    area            (s,) mm^2 tributary areas; default: from the mesh's boundary faces
    search_radius   mm: contact is searched within it (the deepest penetration seen)
    margin          mm: slave motion allowed before the candidate lists are rebuilt
    rest_tolerance  mm: slaves behind the surface at rest by more are dropped
    """

    def __init__(self, mesh, slave_nodes, surface, penalty=PENALTY, name="rigid_contact",
                 area=None, search_radius=3.0, margin=1.0, rest_tolerance=0.1):
        if not penalty > 0:
            raise ParameterError(f"penalty = {penalty!r} must be > 0 (N/mm^3)")
        self.name = name
        self.mesh = mesh
        slaves = np.asarray(slave_nodes, dtype=np.int64).ravel()
        area = _boundary_areas(mesh, slaves) if area is None else \
            np.broadcast_to(np.asarray(area, dtype=np.float64), slaves.shape)
        self.vertices = np.ascontiguousarray(surface.vertices, dtype=np.float64)
        tris = np.ascontiguousarray(surface.triangles, dtype=np.int64)
        self.search_radius, self.margin = float(search_radius), float(margin)
        # orientation: the side of the tissue at each slave (its bricks' mean centroid)
        vote = self._rest_gaps(tris, _tissue_points(mesh, slaves))
        sided = np.isfinite(vote) & (vote != 0)
        if not sided.any():
            raise ParameterError(f"{name}: no slave node faces the surface at rest")
        self.flipped = bool((vote[sided] < 0).sum() > (vote[sided] > 0).sum())
        if self.flipped:
            tris = np.ascontiguousarray(tris[:, ::-1])
        gap0 = self._rest_gaps(tris, mesh.nodes[slaves])
        keep = ~(gap0 < -rest_tolerance)
        self.dropped = slaves[~keep]
        self.slaves = slaves[keep]
        self.initial_gap = gap0[keep]
        self.k = penalty * area[keep]
        self.tris = tris
        self.normals = _Normals(tris, len(self.vertices)).update(self.vertices)
        centroids = self.vertices[tris].mean(axis=1)
        self._tree = cKDTree(centroids)
        self._reach = np.linalg.norm(self.vertices[tris] - centroids[:, None], axis=2).max()
        self._cached = None
        s = len(self.slaves)
        self._fe, self._ke = np.zeros((s, 3)), np.zeros((s, 3, 3))
        self.gap, self.tri = np.full(s, np.inf), -np.ones(s, dtype=np.int64)
        self._report(self.gap, self.k, np.zeros((mesh.n_nodes, 3)))

    def _rest_gaps(self, tris, x):
        """(s,) signed rest gaps of points x (s, 3), whatever their distance."""
        normals = _Normals(tris, len(self.vertices)).update(self.vertices)
        s = len(x)
        ptr, cand = _nearest_lists(self.vertices, tris, x)
        gap = np.empty(s)
        rigid_contact(x, np.zeros(s), self.vertices, tris, ptr, cand, *normals.args(), np.inf,
                      False, np.zeros((s, 3)), np.zeros((s, 3, 3)), gap,
                      -np.ones(s, dtype=np.int64))
        return gap

    def blocks(self):
        return [self.slaves[:, None]]

    def _candidates(self, x):
        """(ptr (s + 1,), triangles) lists, rebuilt when a slave moved more than margin."""
        if self._cached is None or \
                np.linalg.norm(x - self._cached[0], axis=1).max(initial=0.0) > self.margin:
            self._cached = (x.copy(), *_lists(self._tree, x, self.search_radius + self._reach
                                              + self.margin))
        return self._cached[1], self._cached[2]

    def assemble(self, state, asm, block_ids):
        x = self.mesh.nodes[self.slaves] + state.u[self.slaves]
        ptr, cand = self._candidates(x)
        asm.energy += rigid_contact(x, self.k, self.vertices, self.tris, ptr, cand,
                                    *self.normals.args(), self.search_radius, asm.need_k,
                                    self._fe, self._ke, self.gap, self.tri)
        asm.add_block(block_ids[0], self._fe, self._ke if asm.need_k else None)
        force = np.zeros((self.mesh.n_nodes, 3))
        force[self.slaves] = -self._fe
        self._report(self.gap, self.k, force)


class LipContact(Term, _Report):
    """Frictionless two-pass penalty contact between the upper and the lower lip.

    mesh           solver.Mesh
    upper_faces, lower_faces   (f, 3) or (f, 4) node-id faces of the two lip surfaces,
                   oriented outwards (counter-clockwise seen from outside)
    penalty        N/mm^3; node stiffness k_i = penalty * area_i, area_i from its own surface
    radius         mm: candidate pairs are master triangles within radius at rest
    max_pairs      the nearest candidate triangles kept per slave
    depth          mm: deeper penetrations are ignored
    """

    def __init__(self, mesh, upper_faces, lower_faces, penalty=PENALTY, name="lip_contact",
                 radius=6.0, max_pairs=24, depth=2.0):
        if not penalty > 0:
            raise ParameterError(f"penalty = {penalty!r} must be > 0 (N/mm^3)")
        self.name, self.mesh, self.depth = name, mesh, float(depth)
        n = mesh.n_nodes
        surf = [triangulate(upper_faces), triangulate(lower_faces)]
        self.normals = [_Normals(t, n).update(mesh.nodes) for t in surf]
        areas = [tributary_areas(mesh.nodes, t, n) for t in surf]
        self.passes = []
        self.dropped = []
        for s, m in ((0, 1), (1, 0)):
            slaves = np.setdiff1d(np.unique(surf[s]), np.unique(surf[m]))
            slaves, ptr, pair_tri, dropped = self._pairs(slaves, s, m, radius, max_pairs)
            self.dropped.append(dropped)
            p = len(pair_tri)
            self.passes.append({
                "slaves": slaves, "master": m, "ptr": ptr, "pair_tri": pair_tri,
                "k": penalty * areas[s][slaves],
                "nodes": np.column_stack([slaves[np.repeat(np.arange(len(slaves)),
                                                           np.diff(ptr))], surf[m][pair_tri]]),
                "fe": np.zeros((p, 12)), "ke": np.zeros((p, 12, 12)),
                "gap": np.full(len(slaves), np.inf),
                "active": -np.ones(len(slaves), dtype=np.int64)})
        self.dropped = np.concatenate(self.dropped)
        self.slaves = np.concatenate([q["slaves"] for q in self.passes])
        self.k = np.concatenate([q["k"] for q in self.passes])
        self._report(np.full(len(self.slaves), np.inf), self.k, np.zeros((n, 3)))

    @property
    def n_pairs(self):
        return sum(len(q["pair_tri"]) for q in self.passes)

    def _pairs(self, slaves, s, m, radius, max_pairs):
        """Candidate pairs at rest of slaves (nodes of surface s) on the triangles of
        surface m: (kept slaves, ptr, pair triangles, dropped slaves)."""
        x = self.mesh.nodes
        tris, fn = self.normals[m].tris, self.normals[m].fn
        cen = x[tris].mean(axis=1)
        reach = np.linalg.norm(x[tris] - cen[:, None], axis=2).max()
        ptr, ti = _lists(cKDTree(cen), x[slaves], radius + reach)
        si = np.repeat(np.arange(len(slaves)), np.diff(ptr))
        st = self.normals[s].tris
        nrm = np.zeros((len(x), 3))                           # area-weighted slave normals
        np.add.at(nrm, st, np.cross(x[st[:, 1]] - x[st[:, 0]], x[st[:, 2]] - x[st[:, 0]])[:, None])
        d2 = np.empty(len(ti))
        pair_distances(x[slaves[si]], x, tris, ti, d2)
        ok = (d2 <= radius ** 2) & ((nrm[slaves[si]] * fn[ti]).sum(axis=1) < 0)
        order = np.lexsort((d2[ok], si[ok]))                  # by slave, nearest first
        si, ti = si[ok][order], ti[ok][order]
        rank = np.arange(len(si)) - np.searchsorted(si, si)
        si, ti = si[rank < max_pairs], ti[rank < max_pairs]
        ptr = np.searchsorted(si, np.arange(len(slaves) + 1))
        gap = np.empty(len(slaves))
        surface_contact(x, slaves, np.zeros(len(slaves)), tris, ptr, ti, *self.normals[m].args(),
                        np.inf, False, np.zeros((len(ti), 12)), np.zeros((len(ti), 12, 12)),
                        gap, -np.ones(len(slaves), dtype=np.int64))
        inside = gap < 0
        keep = (np.diff(ptr) > 0) & ~inside
        new = np.cumsum(keep) - 1
        sel = keep[si]
        return (slaves[keep], np.searchsorted(new[si[sel]], np.arange(keep.sum() + 1)),
                ti[sel], slaves[inside])

    def blocks(self):
        return [q["nodes"] for q in self.passes]

    def assemble(self, state, asm, block_ids):
        x = self.mesh.nodes + state.u
        force = np.zeros((self.mesh.n_nodes, 3))
        for q, b in zip(self.passes, block_ids):
            nrm = self.normals[q["master"]].update(x)
            asm.energy += surface_contact(x, q["slaves"], q["k"], nrm.tris, q["ptr"],
                                          q["pair_tri"], *nrm.args(), self.depth, asm.need_k,
                                          q["fe"], q["ke"], q["gap"], q["active"])
            asm.add_block(b, q["fe"], q["ke"] if asm.need_k else None)
            act = q["active"][q["active"] >= 0]
            np.add.at(force, q["nodes"][act], -q["fe"][act].reshape(-1, 4, 3))
        self._report(np.concatenate([q["gap"] for q in self.passes]), self.k, force)
