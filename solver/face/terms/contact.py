r"""Frictionless penalty contact: lips on the rigid teeth, lip on lip.

Both terms are node-on-surface: a slave node x meets a triangulated master surface. c is
the closest point of the master's candidate triangles to x, d = x - c, and the signed gap
is g = -|d| if (x - c) . N <= 0, else +|d| (N the pseudo-normal of the closest face, edge
or vertex; n = -d / |d| the outward normal for g < 0). Per slave node i, with the
stiffness k_i = penalty * A_i (A_i the node's area, a quarter of each of its boundary
faces; penalty in N/mm^3):

    Psi_i = 1/2 k_i g^2 (g <= 0, else 0),   dPsi/dx = k_i d,   d2Psi/dx dx = k_i (I - dc/dx)

(k_i n n on a face, k_i (I - t t) on an edge, k_i I at a vertex; a deformable master
triangle's nodes get their share by the envelope theorem, solver.core.kernels.contact). A
node pressed with the force f penetrates by f / k_i: pure penalty, PENALTY = 1 N/mm^3 lip
on lip (a scene's lip_penalty), TEETH_PENALTY = 2 N/mm^3. Beyond a free edge of an open
sheet the penalty fades out over L = fade (1 mm), Psi_i = psi(a) phi(l / L); optionally
(smoothing s > 0 mm, off by default) the law is smoothed over |g| < s (penalty_law).

RigidContact: lips and cheeks on the rigid teeth. The sheet is oriented towards the
tissue; slaves behind it at rest by more than rest_tolerance, or not facing it, are
dropped (.dropped). Candidates: the triangles within search_radius (a cKDTree of their
centroids), rebuilt once a slave has moved by more than margin. ``rest_offset`` (on by
default) gives a slave that the law pushes on at rest a constant offset (.offset) to where
it is force-free: the anatomy as given is the rest state. Rigid surfaces that share a
seam are joined into one term (joined_surfaces).

LipContact: two passes (upper-lip nodes on the lower lip's triangles, and the reverse).
Each lip quad is cut 2 x 2 and each part into four triangles around its centre
(centred_triangles, pair_maps). Candidate pairs (facing triangles within radius, at most
max_pairs a slave) are picked at rest and again at every commit (follow_state); the
sparsity pattern is made again only when a candidate leaves it (blocks_generation) and is
part of the state (pattern_state). Penetrations deeper than depth (0.5 mm) are ignored.

After each assembly both terms hold: gap (s,) signed gaps (inf: no candidate or a free
boundary), force (s,) normal contact forces (N), n_active, max_penetration (mm, >= 0),
total_force (N) and nodal_force (n, 3). ``linear_gaps(u)`` gives each slave's penetration
and its gradient (Newton's contact status prediction, solver.core.contact_update).

Derivation, free edges and rims, the penalty choice, both terms in full: docs/method.md,
section 'Contact: lips on lips, lips and cheeks on the teeth'.
"""

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from solver.core.errors import ParameterError
from solver.core.kernels.contact import (NO_PAIR_FREE, extend_points, min_facing, nearest,
                                         pair_distances, rest_offsets, rigid_contact,
                                         signed_gaps, surface_contact, surface_normals,
                                         surface_normals_part)
from solver.core.kernels.contact_linear import rigid_linear_gaps, surface_linear_gaps
from solver.core.terms.base import Term, pack_parts, unpack_parts

PENALTY = 1.0              # N/mm^3: contact pressure per mm of penetration
TEETH_PENALTY = 2.0        # N/mm^3: lips and cheeks on the rigid teeth (BUC at 1 presses a
                           # cheek node of 5 mm^2 with 0.35 N: 0.035 mm deep)
EDGE_FADE = 1.0            # mm: lip contact fades out over this distance beyond a free edge
TOLERANCE = 0.05           # mm: the deepest penetration the penalty is meant to allow (checks)
FACING_TOLERANCE = 1e-6    # mm: a slave this far behind a master triangle's plane still faces it


def centred_triangles(faces, first, divisions=1):
    """Lip faces as triangles over the real nodes and virtual vertices (ids first,
    first + 1, ...: fixed linear combinations of a face's corners).

    divisions 1: each quad (f, 4) is split into four triangles around its centre (the mean
    of its corners), which stay within an eighth of the quad's warp (the distance between
    its diagonals' midpoints) of its bilinear face, where a split along one diagonal
    leaves up to half of it on one side. divisions 2: each quad is first cut into 2 x 2
    sub-quads at its edge midpoints (shared with the neighbouring faces) and its centre,
    points of its bilinear face, and each sub-quad is split around its own centre: within
    a 32nd of the warp, with four times the triangles. A degenerate quad (a repeated node)
    or an (f, 3) face is a triangle; at divisions 2 it is cut at its edge midpoints into
    four (on a surface of triangles only, divisions 2 is divisions 1: its faces are flat).

    Returns (tris (t, 3), virtual_nodes (c, 4), virtual_weights (c, 4): virtual vertex
    first + v at sum_b virtual_weights[v, b] x[virtual_nodes[v, b]], corners (t, 4) the
    real nodes a triangle's vertices are made of, weights (t, 3, 4): vertex a of triangle
    t = sum_b weights[t, a, b] x[corners[t, b]])."""
    if divisions not in (1, 2):
        raise ParameterError(f"lip contact divisions = {divisions!r} must be 1 or 2")
    faces = np.asarray(faces, dtype=np.int64)
    if faces.shape[1] == 3:
        faces = np.column_stack([faces, faces[:, 2]])
    if not ((faces[:, [0, 1, 2, 3, 0, 1]] != faces[:, [1, 2, 3, 0, 2, 3]]).all(axis=1)).any():
        divisions = 1                           # triangles only: flat, nothing to refine
    vnodes, vweights, tris, corners, weights = [], [], [], [], []
    edge_mid = {}

    def virtual(nodes, w):
        vnodes.append(nodes)
        vweights.append(w)
        return first + len(vnodes) - 1

    def midpoint(a, b):
        key = (min(a, b), max(a, b))
        if key not in edge_mid:
            edge_mid[key] = virtual([a, b, a, b], [0.5, 0.5, 0.0, 0.0])
        return edge_mid[key]

    for f in faces:
        f = [int(v) for v in f]
        u = [v for i, v in enumerate(f) if v not in f[:i]]
        if len(u) == 4:
            n = divisions
            g = np.linspace(-1.0, 1.0, n + 1)

            def bilinear(si, ti):
                return 0.25 * np.array([(1 - si) * (1 - ti), (1 + si) * (1 - ti),
                                        (1 + si) * (1 + ti), (1 - si) * (1 + ti)])

            grid = {}                       # (i, j) -> (vertex id, weights over f)
            for i in range(n + 1):
                for j in range(n + 1):
                    w = bilinear(g[i], g[j])
                    if (i in (0, n)) and (j in (0, n)):
                        vid = f[int(np.argmax(w))]
                    elif i in (0, n) or j in (0, n):
                        ends = np.flatnonzero(w > 1e-12)
                        vid = midpoint(f[ends[0]], f[ends[1]])
                    else:
                        vid = virtual(f, w)
                    grid[i, j] = (vid, w)
            for i in range(n):
                for j in range(n):
                    ring = [grid[i, j], grid[i + 1, j], grid[i + 1, j + 1], grid[i, j + 1]]
                    wc = bilinear(0.5 * (g[i] + g[i + 1]), 0.5 * (g[j] + g[j + 1]))
                    z = virtual(f, wc)
                    for k in range(4):
                        (va, wa), (vb, wb) = ring[k], ring[(k + 1) % 4]
                        tris.append([va, vb, z])
                        corners.append(f)
                        weights.append([wa, wb, wc])
        elif len(u) == 3:
            eye = np.eye(4)
            if divisions == 1:
                tris.append(u)
                corners.append(u + [u[2]])
                weights.append([eye[0], eye[1], eye[2]])
                continue
            m = [midpoint(u[k], u[(k + 1) % 3]) for k in range(3)]
            wm = [0.5 * (eye[k] + eye[(k + 1) % 3]) for k in range(3)]
            for k in range(3):                  # the corner triangles, then the middle one
                tris.append([u[k], m[k], m[k - 1]])
                corners.append(u + [u[2]])
                weights.append([eye[k], wm[k], wm[k - 1]])
            tris.append(m)
            corners.append(u + [u[2]])
            weights.append(wm)
    vn = np.array(vnodes, dtype=np.int64).reshape(-1, 4)
    vw = np.array(vweights, dtype=np.float64).reshape(-1, 4)
    return (np.ascontiguousarray(np.array(tris, dtype=np.int64).reshape(-1, 3)), vn, vw,
            np.ascontiguousarray(np.array(corners, dtype=np.int64).reshape(-1, 4)),
            np.ascontiguousarray(np.array(weights, dtype=np.float64).reshape(-1, 3, 4)))


def tributary_areas(x, faces, n):
    """(n,) node areas of faces (f, 3) or (f, 4) over points x: each face's area shared
    equally by its corners (a node repeated in a degenerate quad takes two shares)."""
    faces = np.asarray(faces, dtype=np.int64)
    if faces.shape[1] == 3:
        a = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    else:
        a = np.cross(x[faces[:, 2]] - x[faces[:, 0]], x[faces[:, 3]] - x[faces[:, 1]])
    share = 0.5 * np.linalg.norm(a, axis=1) / faces.shape[1]
    return np.bincount(faces.ravel(), np.repeat(share, faces.shape[1]), minlength=n)


class _Topology:
    """Edge neighbours of triangles tris (t, 3) over p points: nbr (t, 3) the triangle
    across edge j = (j, j + 1 mod 3) or -1, free_edge (t, 3), free_vertex (p,). An edge
    without a neighbour whose two nodes are in mirror (p,) bool (the symmetry plane x = 0 of
    a half model) is a mirror edge (mirror_edge (t, 3)), not free; mirror_vertex (p,)
    marks its nodes."""

    def __init__(self, tris, p, mirror=None):
        t = len(tris)
        edges = np.stack([tris, np.roll(tris, -1, axis=1)], axis=2)        # (t, 3, 2)
        _, inv, count = np.unique(np.sort(edges.reshape(-1, 2), axis=1), axis=0,
                                  return_inverse=True, return_counts=True)
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
        on_plane = np.zeros((t, 3), dtype=bool) if mirror is None else mirror[edges].all(axis=2)
        self.mirror_edge = (self.nbr < 0) & on_plane
        self.free_edge = (self.nbr < 0) & ~on_plane
        self.free_vertex = np.zeros(p, dtype=bool)
        self.free_vertex[edges[self.free_edge].ravel()] = True
        self.mirror_vertex = np.zeros(p, dtype=bool)
        self.mirror_vertex[edges[self.mirror_edge].ravel()] = True
        # free vertex v -> its two free edges: the other ends (p, 2) and the triangles
        # (p, 2) (-1 where a vertex has not exactly two: the fade takes its normal vn)
        self.rim_other = -np.ones((p, 2), dtype=np.int64)
        self.rim_tri = -np.ones((p, 2), dtype=np.int64)
        tf, jf = np.nonzero(self.free_edge)
        ends = edges[tf, jf]                                              # (f, 2)
        v = np.concatenate([ends[:, 0], ends[:, 1]])
        other = np.concatenate([ends[:, 1], ends[:, 0]])
        tri = np.concatenate([tf, tf])
        order = np.argsort(v, kind="stable")
        v, other, tri = v[order], other[order], tri[order]
        first = np.searchsorted(v, v)
        two = np.bincount(v, minlength=p)[v] == 2
        slot = np.arange(len(v)) - first
        self.rim_other[v[two], slot[two]] = other[two]
        self.rim_tri[v[two], slot[two]] = tri[two]


@dataclass(frozen=True)
class _NormalsPart:
    """Rows of a _Normals update: rows, surface_normals_part's (faces, ring, verts, mark,
    edges); me, mv: the mirror edges (t, j) and vertices among them."""
    rows: tuple
    me: tuple
    mv: np.ndarray


class _Normals:
    """Face, edge and vertex (pseudo-)normals of a triangle surface, refreshed by update;
    on mirror edges and vertices (see _Topology) the normals of the mirrored surface
    (x -> -x) are included: their x component vanishes."""

    def __init__(self, tris, p, mirror=None):
        self.tris = tris
        self.verts = np.unique(tris)
        self.topo = _Topology(tris, p, mirror)
        self.fn = np.empty((len(tris), 3))
        self.en = np.empty((len(tris), 3, 3))
        self.vn = np.empty((p, 3))
        self._me = np.nonzero(self.topo.mirror_edge)
        self._mv = np.flatnonzero(self.topo.mirror_vertex)
        self._at = None             # the vertices' positions of the last whole update

    def update(self, x, part=None):
        """Refresh the normals at the points x (p, 3): all of them (nothing to do where
        the surface's vertices are where the last whole update had them), or the rows of
        a part (changed() or read())."""
        if part is None:
            at = x[self.verts]
            if self._at is not None and np.array_equal(at, self._at):
                return self
            surface_normals(x, self.tris, self.topo.nbr, self.verts, self.fn, self.en, self.vn)
            me, mv = self._me, self._mv
            self._at = at
        else:
            self._at = None
            surface_normals_part(x, self.tris, self.topo.nbr, *part.rows, self.fn, self.en,
                                 self.vn)
            me, mv = part.me, part.mv
        for n, rows in ((self.en, me), (self.vn, mv)):
            m = n[rows]
            m[:, 0] = 0.0
            n[rows] = m / np.linalg.norm(m, axis=1)[:, None]
        return self

    def changed(self, moved):
        """The part of the normals that a motion of the vertices moved (p,) bool changes:
        the faces with a moved vertex, their vertices' normals and the edges of those
        faces and their neighbours (an update of it equals a whole one)."""
        faces = np.flatnonzero(moved[self.tris].any(axis=1))
        nbr = self.topo.nbr[faces]
        edges = np.union1d(faces, nbr[nbr >= 0])
        return self._part(faces, np.unique(self.tris[faces]), edges)

    def read(self, tris):
        """The part of the normals that a contact kernel reads on the triangles tris (k,)
        (their faces, edges and vertices), for an update where every vertex may move."""
        tris = np.unique(tris)
        return self._part(None, np.unique(self.tris[tris]), tris)

    def _part(self, faces, verts, edges):
        """faces None: the ring (every triangle with a vertex in verts; it holds edges)."""
        mark = np.zeros(len(self.vn), dtype=bool)
        mark[verts] = True
        ring = np.flatnonzero(mark[self.tris].any(axis=1))
        faces = ring if faces is None else faces
        in_edges = np.isin(self._me[0], edges)
        return _NormalsPart(
            rows=(np.ascontiguousarray(faces, dtype=np.int64),
                  np.ascontiguousarray(ring, dtype=np.int64),
                  np.ascontiguousarray(verts, dtype=np.int64), mark,
                  np.ascontiguousarray(edges, dtype=np.int64)),
            me=(self._me[0][in_edges], self._me[1][in_edges]),
            mv=self._mv[mark[self._mv]])

    def args(self):
        """The kernels' (fn, en, vn, free_edge, free_vertex)."""
        return self.fn, self.en, self.vn, self.topo.free_edge, self.topo.free_vertex


def _lists(tree, x, r):
    """CSR lists (ptr (s + 1,), ids) of the tree's points within r (scalar or (s,)) of
    the points x (s, 3)."""
    lists = tree.query_ball_point(x, r)
    ptr = np.zeros(len(x) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(c) for c in lists])
    return ptr, np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64,
                            count=ptr[-1])


def _nearest_lists(xv, tris, x):
    """Candidate lists (ptr, triangles) of points x (s, 3) that hold each point's nearest
    triangle: the centroids within (distance to the nearest centroid + reach)."""
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
    w, wt = np.empty(3), np.empty(3)
    return np.sqrt([nearest(p, xv, tris, cand[a:b], w, wt)[2]
                    for p, a, b in zip(x, ptr[:-1], ptr[1:])])


def nodes_near(mesh, nodes, surface, distance):
    """The node ids (k,) among nodes whose rest distance to surface is <= distance (mm)."""
    nodes = np.asarray(nodes, dtype=np.int64)
    return nodes[surface_distance(mesh.nodes[nodes], surface) <= distance]


def _facing_areas(mesh, nodes, xv, tris, fn):
    """(s,) areas of nodes projected on the rigid surface: each boundary face of the mesh
    shares its area, projected on the normal fn of the surface triangle nearest to it
    (zero where it does not face the surface), equally among its corners."""
    faces = mesh.boundary_faces()
    faces = faces[np.isin(faces, nodes).any(axis=1)]
    x = mesh.nodes
    a = 0.5 * np.cross(x[faces[:, 2]] - x[faces[:, 0]], x[faces[:, 3]] - x[faces[:, 1]])
    cen = x[faces].mean(axis=1)
    ptr, cand = _nearest_lists(xv, tris, cen)
    w, wt = np.empty(3), np.empty(3)
    t = np.array([cand[lo + nearest(c, xv, tris, cand[lo:hi], w, wt)[0]]
                  for c, lo, hi in zip(cen, ptr[:-1], ptr[1:])], dtype=np.int64)
    share = np.maximum(0.0, -(a * fn[t]).sum(axis=1)) / 4.0
    return np.bincount(faces.ravel(), np.repeat(share, 4), minlength=mesh.n_nodes)[nodes]


def _tissue_points(mesh, nodes):
    """(s, 3) the mean centroid of the bricks around each node: a point on its tissue side."""
    cen = np.repeat(mesh.nodes[mesh.bricks].mean(axis=1), 8, axis=0)
    acc = np.zeros((mesh.n_nodes, 3))
    np.add.at(acc, mesh.bricks.ravel(), cen)
    count = np.bincount(mesh.bricks.ravel(), minlength=mesh.n_nodes)
    return acc[nodes] / count[nodes, None]


def _incidence(tris, n):
    """CSR lists (ptr (n + 1,), triangle ids) of the triangles at each of n nodes."""
    node = tris.ravel()
    order = np.argsort(node, kind="stable")
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(node, minlength=n), out=ptr[1:])
    return ptr, order // 3


def _check(penalty, smoothing):
    if not penalty > 0:
        raise ParameterError(f"penalty = {penalty!r} must be > 0 (N/mm^3)")
    if not smoothing >= 0:
        raise ParameterError(f"smoothing = {smoothing!r} must be >= 0 (mm)")


class _Report:
    """Contact measures of the last assembly (see the module docstring); ``touching()``
    (n,) bool: the mesh nodes the contact pushed on then (solver.core.transient leaves the nodes
    touched at either end of a step out of its error estimate)."""

    nonsmooth = True

    def touching(self):
        return np.any(self.nodal_force != 0.0, axis=1)

    @property
    def penalty(self):
        """N/mm^3; setting it rescales the slaves' stiffnesses (an experiment's knob:
        benchmarks/fast_path.py --set contact.penalty=P)."""
        return self._penalty

    @penalty.setter
    def penalty(self, value):
        _check(value, self.smoothing)
        scale = value / self._penalty
        for k in self._stiffnesses():
            k *= scale
        self._penalty = float(value)

    def _report(self, gap, force, nodal_force):
        active = gap <= 0
        self.gap, self.force, self.nodal_force = gap, force, nodal_force
        self.n_active = int(active.sum())
        self.max_penetration = float(-gap[active].min()) if self.n_active else 0.0
        self.total_force = float(force.sum())


class RigidContact(_Report, Term):
    """Frictionless penalty contact of slave nodes on a rigid triangulated surface.

    mesh            solver.Mesh
    slave_nodes     (s,) node ids that may touch (e.g. lip nodes near the teeth)
    surface         solver.face.anatomy.RigidSurface (vertices (p, 3), triangles (t, 3))
    penalty         N/mm^3; node stiffness k_i = penalty * area_i (N/mm)
    area            (s,) mm^2 node areas; default: the mesh's boundary faces around each
                    slave, projected on the surface's normal
    search_radius   mm: contact is searched within it (the deepest penetration seen)
    margin          mm: slave motion allowed before the candidate lists are rebuilt
    rest_tolerance  mm: slaves behind the surface at rest by more are dropped
    smoothing       mm: the penalty law is smoothed over |g| < smoothing (0: pure penalty)
    fade            mm: beyond a free edge or vertex of the sheet the penalty fades over
                    this length (0: a node there is released)
    rest_offset     move the slaves that the law pushes on at rest onto the surface by a
                    constant offset each (.offset (s, 3)), so that the rest state carries
                    no contact force (see the module docstring)
    motion          (jaw, moving) or None: the vertices flagged moving (p,) follow the
                    rigid pose jaw.at(lam) of a solver.face.jaw.Jaw (the lower teeth)
    """

    def __init__(self, mesh, slave_nodes, surface, penalty=PENALTY, name="rigid_contact",
                 area=None, search_radius=3.0, margin=1.0, rest_tolerance=0.1, smoothing=0.0,
                 fade=EDGE_FADE, rest_offset=True, motion=None):
        _check(penalty, smoothing)
        if not fade >= 0:
            raise ParameterError(f"{name}: fade = {fade!r} must be >= 0 (mm)")
        self.name, self.mesh, self.smoothing = name, mesh, float(smoothing)
        self.fade = float(fade)
        slaves = np.asarray(slave_nodes, dtype=np.int64).ravel()
        self.vertices = np.ascontiguousarray(surface.vertices, dtype=np.float64)
        tris = np.ascontiguousarray(surface.triangles, dtype=np.int64)
        self.search_radius, self.margin = float(search_radius), float(margin)
        vote = self._rest_gaps(tris, _tissue_points(mesh, slaves))
        sided = np.isfinite(vote) & (vote != 0)
        if not sided.any():
            raise ParameterError(f"{name}: no slave node faces the surface at rest")
        self.flipped = bool((vote[sided] < 0).sum() > (vote[sided] > 0).sum())
        if self.flipped:
            tris = np.ascontiguousarray(tris[:, ::-1])
        self.tris = tris
        self.normals = _Normals(tris, len(self.vertices)).update(self.vertices)
        area = _facing_areas(mesh, slaves, self.vertices, tris, self.normals.fn) \
            if area is None else np.broadcast_to(np.asarray(area, dtype=np.float64), slaves.shape)
        gap0 = self._rest_gaps(tris, mesh.nodes[slaves])
        keep = ~(gap0 < -rest_tolerance) & (area > 0)
        self.dropped = slaves[~keep]
        self.slaves = slaves[keep]
        self.initial_gap = gap0[keep]
        self._penalty = float(penalty)
        self.k = penalty * area[keep]
        centroids = self.vertices[tris].mean(axis=1)
        self._tree = cKDTree(centroids)
        self._reach = np.linalg.norm(self.vertices[tris] - centroids[:, None], axis=2).max()
        self._cached = None
        s = len(self.slaves)
        self._fe, self._ke = np.zeros((s, 3)), np.zeros((s, 3, 3))
        self.tri = -np.ones(s, dtype=np.int64)
        self.offset = np.zeros((s, 3))
        self.x0 = mesh.nodes[self.slaves]
        if rest_offset:
            self.offset = self._rest_offsets()
            self.x0 = self.x0 + self.offset
        self._report(np.full(s, np.inf), np.zeros(s), np.zeros((mesh.n_nodes, 3)))
        self.motion, self.rest_vertices = motion, self.vertices.copy()
        self.pose = np.zeros(2)
        self._moved = None

    def _move(self, lam):
        """Put the moving vertices at the jaw's pose at load factor lam."""
        self.move_to(self.motion[0].at(lam))

    def move_to(self, pose):
        """Put the moving vertices at a jaw pose (2,) (normals and the candidate search
        follow); nothing to do where the pose is unchanged."""
        jaw, moving = self.motion
        pose = np.array(pose, dtype=np.float64)
        if np.array_equal(pose, self.pose):
            return
        self.pose = pose
        v = self.rest_vertices.copy()
        if np.any(pose != 0.0):
            v[moving] = jaw.geometry.transform(v[moving], pose)
        self.vertices = np.ascontiguousarray(v)
        if self._moved is None:                      # the rows the jaw's motion changes
            self._moved = self.normals.changed(moving)
        self.normals.update(self.vertices, self._moved)
        self._tree = None                 # the candidate search's, rebuilt when needed

    def _stiffnesses(self):
        return [self.k]

    def _rest_offsets(self):
        """(s, 3) the offsets that put the slaves pushed on at rest where the law is
        force-free (solver.core.kernels.contact.rest_offsets); zero for the others."""
        x = self.mesh.nodes[self.slaves]
        ptr, cand = self._candidates(x)
        s = len(x)
        gap, force = np.empty(s), np.empty(s)
        rigid_contact(x, self.k, self.vertices, self.tris, ptr, cand, *self.normals.args(),
                      self.search_radius, self.smoothing, False, self._fe, self._ke, gap, force,
                      self.tri, *self.rim_args())
        out = np.zeros((s, 3))
        rest_offsets(x, self.vertices, self.tris, ptr, cand, *self.normals.args(),
                     self.smoothing, *self.rim_args()[1:], force > 0.0, out)
        self._cached = None
        return out

    def rim_args(self):
        """The kernel's (fade, rim_other, rim_tri) (solver.core.kernels.contact.rigid_contact)."""
        topo = self.normals.topo
        return self.fade, topo.rim_other, topo.rim_tri

    def _rest_gaps(self, tris, x):
        """(s,) signed gaps of points x (s, 3) to the triangles tris, whatever their
        distance."""
        normals = _Normals(tris, len(self.vertices)).update(self.vertices)
        ptr, cand = _nearest_lists(self.vertices, tris, x)
        gap = np.empty(len(x))
        signed_gaps(np.ascontiguousarray(x), self.vertices, tris, ptr, cand, *normals.args(),
                    gap)
        return gap

    def blocks(self):
        return [self.slaves[:, None]]

    def _candidates(self, x):
        """(ptr (s + 1,), triangles) lists, rebuilt once ds + 3 dv > margin: ds the
        slaves' and dv the surface vertices' largest motion since they were made (a
        triangle's centroid moves by at most dv and its reach grows by at most 2 dv, so
        every triangle within search_radius stays a candidate)."""
        cached = self._cached
        if cached is None or self._moved_by(x, cached) > self.margin:
            if self._tree is None:
                corners = self.vertices[self.tris]
                centroids = corners.mean(axis=1)
                self._tree = cKDTree(centroids)
                self._reach = np.linalg.norm(corners - centroids[:, None], axis=2).max()
            self._cached = (x.copy(), self.vertices,
                            *_lists(self._tree, x, self.search_radius + self._reach
                                    + self.margin))
        return self._cached[2], self._cached[3]

    def _moved_by(self, x, cached):
        """ds + 3 dv (mm) since the candidate lists cached = (x, vertices, ...) were made."""
        ds = np.linalg.norm(x - cached[0], axis=1).max(initial=0.0)
        if cached[1] is self.vertices:
            return ds
        return ds + 3.0 * np.linalg.norm(self.vertices - cached[1], axis=1).max(initial=0.0)

    def assemble(self, state, asm, block_ids):
        if self.motion is not None:
            self._move(state.lam)
        x = self.x0 + state.u[self.slaves]
        ptr, cand = self._candidates(x)
        gap, force = np.empty(len(x)), np.empty(len(x))
        asm.energy += rigid_contact(x, self.k, self.vertices, self.tris, ptr, cand,
                                    *self.normals.args(), self.search_radius, self.smoothing,
                                    asm.need_k, self._fe, self._ke, gap, force, self.tri,
                                    *self.rim_args())
        asm.add_block(block_ids[0], self._fe, self._ke if asm.need_k else None)
        nodal = np.zeros((self.mesh.n_nodes, 3))
        nodal[self.slaves] = -self._fe
        self._report(gap, force, nodal)

    def linear_gaps(self, u):
        """The slaves' linearized penetrations at displacements u (n, 3) (solver.
        contact_update): (dofs (s, 3), v (s, 3), k (s,), p (s,)), p nan where no law
        applies; None with a smoothed law."""
        if self.smoothing > 0:
            return None
        x = self.x0 + u[self.slaves]
        ptr, cand = self._candidates(x)
        p, v = np.empty(len(x)), np.empty((len(x), 3))
        rigid_linear_gaps(x, self.vertices, self.tris, ptr, cand, *self.normals.args(),
                          self.search_radius, p, v)
        return 3 * self.slaves[:, None] + np.arange(3), v, self.k, p


class LipContact(_Report, Term):
    """Frictionless two-pass penalty contact between the upper and the lower lip.

    mesh           solver.Mesh
    upper_faces, lower_faces   (f, 3) or (f, 4) node-id faces of the two lip surfaces,
                   oriented outwards (counter-clockwise seen from outside)
    penalty        N/mm^3; node stiffness k_i = penalty * area_i, area_i from its own surface
    radius         mm: candidate pairs are master triangles within radius at rest
    max_pairs      the nearest candidate triangles kept per slave (see above)
    depth          mm: deeper penetrations are ignored
    rest_tolerance mm: slaves inside the other lip at rest by more are dropped
    smoothing      mm: the penalty law is smoothed over |g| < smoothing (0: pure penalty)
    mirror_nodes   node ids on the symmetry plane x = 0 of a half model (its 'midsagittal'
                   set): surface edges between two of them are mirrored, not free
    fade           mm: beyond a free edge (of the surface or of a slave's candidates) the
                   penalty fades over this length
    follow         the candidate pairs follow the converged state: at every commit (and
                   follow_state) they are picked again as at rest, at the current positions
    behind         mm: a candidate triangle may have the slave this far behind its plane
                   (default depth: a penetrating slave keeps the triangle it is in)
    divisions      1 or 2: the lip faces' triangulation (centred_triangles; 2: the
                   quads' 2 x 2 subdivision, a 32nd of their warp from the bilinear faces)
    pattern_margin mm: the pattern block reaches this much beyond radius (follow only)
    """

    def __init__(self, mesh, upper_faces, lower_faces, penalty=PENALTY, name="lip_contact",
                 radius=6.0, max_pairs=48, depth=0.5, rest_tolerance=0.1, smoothing=0.0,
                 mirror_nodes=None, fade=EDGE_FADE, follow=True, behind=None, divisions=2,
                 pattern_margin=3.0):
        _check(penalty, smoothing)
        if not fade > 0:
            raise ParameterError(f"{name}: fade = {fade!r} must be > 0 (mm)")
        if not pattern_margin >= 0:
            raise ParameterError(f"{name}: pattern_margin = {pattern_margin!r} must be >= 0 "
                                 "(mm)")
        self.name, self.mesh, self.fade = name, mesh, float(fade)
        self.depth, self.smoothing = float(depth), float(smoothing)
        self.behind = self.depth if behind is None else float(behind)
        self._penalty = float(penalty)
        n = mesh.n_nodes
        mirror = None
        if mirror_nodes is not None:
            mirror = np.zeros(n, dtype=bool)
            mirror[np.asarray(mirror_nodes, dtype=np.int64)] = True
        surf, vnodes, vweights, corners, weights = [], [], [], [], []
        first = n
        for faces in (upper_faces, lower_faces):
            t, vn, vw, co, w = centred_triangles(faces, first, divisions)
            surf.append(t)
            vnodes.append(vn)
            vweights.append(vw)
            corners.append(co)
            weights.append(w)
            first += len(vn)
        self.divisions = int(divisions)
        self.virtual_nodes = np.vstack(vnodes)                # (c, 4) virtual vertices'
        self.virtual_weights = np.vstack(vweights)            # (c, 4) combinations
        ext = None if mirror is None else np.concatenate([mirror, np.zeros(first - n, bool)])
        x0 = self.positions(np.zeros((n, 3)))
        self.normals = [_Normals(t, first, ext).update(x0) for t in surf]
        areas = [tributary_areas(mesh.nodes, f, n) for f in (upper_faces, lower_faces)]
        real = [np.unique(np.asarray(f)) for f in (upper_faces, lower_faces)]
        self.radius, self.max_pairs, self.follow = float(radius), int(max_pairs), follow
        self.pattern_margin = float(pattern_margin)
        self._corners, self._weights = corners, weights
        # a pattern row is a slave and the four nodes of a quad, in the order its
        # triangles' pairs scatter them (the distinct rows of corners)
        self._quads, self._quad_of = [], []
        for co in corners:
            quads, of = np.unique(np.asarray(co), axis=0, return_inverse=True)
            self._quads.append(quads)
            self._quad_of.append(of.ravel())
        self.passes, dropped = [], []
        for s, m in ((0, 1), (1, 0)):
            slaves = np.setdiff1d(real[s], real[m])
            ptr, pair_tri, pair_free = self._pairs(x0, slaves, s, m)
            gap = self._rest_gaps(x0, slaves, m, ptr, pair_tri)
            # a slave without candidates at rest gets them where it comes near the other
            # lip when the pairs follow the state; without follow it never would
            keep = ((np.diff(ptr) > 0) | follow) & ~(gap < -rest_tolerance)
            dropped.append(slaves[(gap < -rest_tolerance)])
            slaves = slaves[keep]
            q = {"slaves": slaves, "slave_surface": s, "master": m,
                 "k": penalty * areas[s][slaves]}
            self._set_pairs(q, *self._pairs(x0, slaves, s, m))
            self._widen(q, x0)
            self.passes.append(q)
        self.dropped = np.concatenate(dropped)
        self.slaves = np.concatenate([q["slaves"] for q in self.passes])
        s = len(self.slaves)
        self._report(np.full(s, np.inf), np.zeros(s), np.zeros((n, 3)))

    def _stiffnesses(self):
        return [q["k"] for q in self.passes]

    @property
    def k(self):
        """(s,) the slaves' stiffnesses (N/mm), both passes, in the order of slaves."""
        return np.concatenate(self._stiffnesses())

    def positions(self, u):
        """(n + c, 3) the nodes' positions at displacements u (n, 3), then the virtual
        vertices of the lip surfaces (centred_triangles)."""
        return self.extend(self.mesh.nodes + u)

    def extend(self, x, out=None):
        """(n + c, 3): node positions x (n, 3), then the virtual vertices' (into out when
        given)."""
        if out is None:
            out = np.empty((len(x) + len(self.virtual_nodes), 3))
        extend_points(x, self.virtual_nodes, self.virtual_weights, out)
        return out

    def _set_pairs(self, q, ptr, pair_tri, pair_free):
        """Put the candidate pairs (ptr, pair triangles, pair_free) in the pass q, with the
        pair's real nodes (slave, the 4 of its triangle's quad) and the triangle's vertices
        in terms of them (pair_weights (p, 3, 4)); no pair active."""
        slaves, m = q["slaves"], q["master"]
        owner = np.repeat(np.arange(len(slaves)), np.diff(ptr))
        p = len(pair_tri)
        q.update({"ptr": ptr, "pair_tri": pair_tri, "pair_free": pair_free,
                  "nodes": np.column_stack([slaves[owner], self._corners[m][pair_tri]]),
                  "pair_weights": np.ascontiguousarray(self._weights[m][pair_tri]),
                  "fe": np.zeros((p, 12)), "ke": np.zeros((p, 12, 12)),
                  "active": -np.ones(len(slaves), dtype=np.int64),
                  "kept": -np.ones(len(slaves), dtype=np.int64),
                  "keys": owner * len(self._quads[m]) + self._quad_of[m][pair_tri]})
        q["rows"] = self._rows(q)

    @staticmethod
    def _rows(q):
        """(p,) each candidate pair's row in the pass's pattern block, or None when one of
        them has no row there."""
        bk, keys = q.get("block_keys"), q["keys"]
        if bk is None or (len(keys) and not len(bk)):
            return None
        at = np.minimum(np.searchsorted(bk, keys), max(len(bk) - 1, 0))
        return at if np.array_equal(bk[at], keys) else None

    def _set_block(self, q, keys):
        """The pass's pattern block: rows (slave, the 4 nodes of a quad) for the sorted
        unique keys slave position * quads + quad; the candidate pairs' rows in it."""
        m, nq = q["master"], len(self._quads[q["master"]])
        q["block_keys"] = keys
        q["block"] = np.column_stack([q["slaves"][keys // nq], self._quads[m][keys % nq]])
        q["rows"] = self._rows(q)

    def _widen(self, q, x):
        """A new pattern block for the pass at positions x: the (slave, quad) pairs of
        every triangle within radius + pattern_margin, facing or not, and the current
        candidates' (module docstring: the pattern is kept while the candidates stay in
        it)."""
        keys = q["keys"]
        if self.follow and self.pattern_margin > 0:
            ptr, tri, _ = self._pairs(x, q["slaves"], q["slave_surface"], q["master"],
                                      self.radius + self.pattern_margin,
                                      facing_only=False)
            owner = np.repeat(np.arange(len(q["slaves"])), np.diff(ptr))
            keys = np.concatenate([keys, owner * len(self._quads[q["master"]])
                                   + self._quad_of[q["master"]][tri]])
        self._set_block(q, np.unique(keys).astype(np.int64))

    def pattern_state(self):
        """(k,) int64: the passes' pattern blocks (their lengths, then their keys), for
        set_pattern_state: a state restored with it gets back the pattern it had."""
        return pack_parts(q["block_keys"] for q in self.passes)

    def set_pattern_state(self, data):
        """The pattern blocks of pattern_state(), or None: new ones at the next
        follow_state (then picked from that state alone)."""
        if data is None:
            for q in self.passes:
                q["block_keys"], q["rows"] = None, None
            return
        parts = unpack_parts(data, len(self.passes), f"{self.name}: a pattern state")
        for q, keys in zip(self.passes, parts):
            top = len(q["slaves"]) * len(self._quads[q["master"]])
            if len(keys) and (keys.min() < 0 or keys.max() >= top or np.any(np.diff(keys) <= 0)):
                raise ValueError(f"{self.name}: a pattern state's keys are not this term's")
        changed = False
        for q, keys in zip(self.passes, parts):
            if q.get("block_keys") is None or not np.array_equal(keys, q["block_keys"]):
                self._set_block(q, keys.copy())
                changed = True
        if changed:
            self.blocks_generation += 1

    def follow_state(self, u):
        """The candidate pairs of the configuration u (n, 3) (follow: the pairs that
        _pairs picks there, as at rest); a change increments blocks_generation."""
        if not self.follow:
            return
        x = self.positions(u)
        changed = False
        for q in self.passes:
            self.normals[q["master"]].update(x)
            self.normals[q["slave_surface"]].update(x)
            ptr, tri, free = self._pairs(x, q["slaves"], q["slave_surface"], q["master"])
            if not (np.array_equal(ptr, q["ptr"]) and np.array_equal(tri, q["pair_tri"])
                    and np.array_equal(free, q["pair_free"])):
                self._set_pairs(q, ptr, tri, free)
            if q["rows"] is None:                  # a candidate outside the pattern block
                self._widen(q, x)
                changed = True
        if changed:
            self.blocks_generation += 1

    def commit(self, state):
        self.follow_state(state.u)

    def _rest_gaps(self, x, slaves, m, ptr, pair_tri):
        """(s,) the slaves' signed gaps to their candidates at positions x."""
        ns = len(slaves)
        gap = np.empty(ns)
        surface_contact(x, slaves, np.zeros(ns), self.normals[m].tris, ptr, pair_tri,
                        *self.normals[m].args(), np.inf, 0.0, False,
                        np.zeros((len(pair_tri), 12)), np.zeros((len(pair_tri), 12, 12)),
                        gap, np.zeros(ns), -np.ones(ns, dtype=np.int64),
                        -np.ones(ns, dtype=np.int64), NO_PAIR_FREE, 1.0)
        return gap

    def _pairs(self, x, slaves, s, m, radius=None, facing_only=True):
        """Candidate pairs at positions x (n + c, 3) of slaves (nodes of surface s) on the
        triangles of surface m: the max_pairs nearest within radius that the slave's
        surface faces and that the slave is not behind by more than depth; (ptr (s + 1,),
        pair triangles (p,), pair_free (p, 3)). facing_only False: every triangle within
        radius, with no count cap (the pattern block)."""
        radius = self.radius if radius is None else radius
        max_pairs = self.max_pairs if facing_only else None
        tris, fn = self.normals[m].tris, self.normals[m].fn
        cen = x[tris].mean(axis=1)
        reach = np.linalg.norm(x[tris] - cen[:, None], axis=2).max()
        ptr, ti = _lists(cKDTree(cen), x[slaves], radius + reach)
        si = np.repeat(np.arange(len(slaves)), np.diff(ptr))
        st = self.normals[s].tris
        sn = self.normals[s].fn                               # the slave surface's faces
        d2 = np.empty(len(ti))
        pair_distances(x[slaves[si]], x, tris, ti, d2)
        ok = d2 <= radius ** 2
        if facing_only:
            ahead = ((x[slaves[si]] - x[tris[ti, 0]]) * fn[ti]).sum(axis=1)  # plane distance
            inc_p, inc_t = _incidence(st, len(x))
            facing = np.empty(len(ti))
            min_facing(inc_p, inc_t, sn, slaves[si], fn[ti], facing)
            ok &= (facing < 0) & (ahead > -FACING_TOLERANCE - self.behind)
        order = np.lexsort((d2[ok], si[ok]))                  # by slave, nearest first
        si, ti = si[ok][order], ti[ok][order]
        if max_pairs is not None:
            first = np.arange(len(si)) - np.searchsorted(si, si) < max_pairs
            si, ti = si[first], ti[first]
        ptr = np.searchsorted(si, np.arange(len(slaves) + 1))
        # an edge is free for a slave when it borders none of the slave's other candidates
        nbr = self.normals[m].topo.nbr[ti]                               # (p, 3)
        key = si * len(tris) + ti
        inner = np.isin(si[:, None] * len(tris) + nbr, key) | (nbr < 0)
        free = ~inner | self.normals[m].topo.free_edge[ti]
        return ptr, ti, np.ascontiguousarray(free)

    def blocks(self):
        return [q["block"] for q in self.passes]

    def assemble(self, state, asm, block_ids):
        x = self.positions(state.u)
        nodal = np.zeros((self.mesh.n_nodes, 3))
        gaps, forces = [], []
        for q, b in zip(self.passes, block_ids):
            nrm = self.normals[q["master"]].update(x)
            gap, force = np.empty(len(q["slaves"])), np.empty(len(q["slaves"]))
            asm.energy += surface_contact(x, q["slaves"], q["k"], nrm.tris, q["ptr"],
                                          q["pair_tri"], *nrm.args(), self.depth, self.smoothing,
                                          asm.need_k, q["fe"], q["ke"], gap, force,
                                          q["active"], q["kept"], q["pair_free"], self.fade)
            act = q["active"][q["active"] >= 0]
            T = pair_maps(q["pair_weights"][act])
            Tt = T.transpose(0, 2, 1)
            fe = (Tt @ q["fe"][act][:, :, None])[:, :, 0]
            ke = Tt @ q["ke"][act] @ T if asm.need_k else None
            asm.add_block(b, fe, ke, rows=q["rows"][act])
            np.add.at(nodal, q["nodes"][act], -fe.reshape(-1, 5, 3))
            gaps.append(gap)
            forces.append(force)
        self._report(np.concatenate(gaps), np.concatenate(forces), nodal)

    def linear_gaps(self, u):
        """As RigidContact.linear_gaps, both passes (dofs (s, 15) over the slave and the
        real nodes of its nearest candidate triangle's quad, v (s, 15))."""
        if self.smoothing > 0:
            return None
        x = self.positions(u)
        out = []
        for q in self.passes:
            nrm = self.normals[q["master"]].update(x)
            s = len(q["slaves"])
            if not len(q["pair_tri"]):            # no candidates (lips apart): no law
                out.append((np.zeros((s, 15), dtype=np.int64), np.zeros((s, 15)), q["k"],
                            np.full(s, np.nan)))
                continue
            p, v, pair = np.empty(s), np.empty((s, 12)), np.empty(s, dtype=np.int64)
            surface_linear_gaps(x, q["slaves"], nrm.tris, q["ptr"], q["pair_tri"], *nrm.args(),
                                self.depth, q["pair_free"], p, v, pair)
            at = np.maximum(pair, 0)
            v = np.einsum("pij,pi->pj", pair_maps(q["pair_weights"][at]), v)
            out.append((3 * np.repeat(q["nodes"][at], 3, axis=1) + np.tile(np.arange(3), 5),
                        v, q["k"], p))
        return tuple(np.concatenate(a) for a in zip(*out))


def pair_maps(weights):
    """(p, 12, 15) T: the pair's 12 kernel dofs (slave, the triangle's 3 vertices) in
    terms of its 15 real ones (slave, the quad's 4 nodes), from weights (p, 3, 4); a
    force f over the kernel's dofs is T^T f over the real ones, a tangent T^T K T."""
    T = np.zeros((len(weights), 12, 15))
    T[:, :3, :3] = np.eye(3)
    T[:, 3:, 3:] = np.einsum("pab,ij->paibj", weights, np.eye(3)).reshape(-1, 9, 12)
    return T


def joined_surfaces(surfaces, tol=1e-9):
    """{name: RigidSurface} with the surfaces that share vertices (within tol mm) joined
    into one (named 'a+b'): a seam between two sheets of one rigid body is then an inner
    edge, not two free edges (at a free edge a slave is released, so a slave sliding over
    the seam would be pushed by one sheet, then by neither, then by the other)."""
    from solver.face.anatomy.base import RigidSurface

    groups = [(name, np.asarray(s.vertices, float), np.asarray(s.triangles, np.int64))
              for name, s in surfaces.items()]
    merged = True
    while merged and len(groups) > 1:
        merged = False
        for i in range(len(groups)):
            for j in range(i + 1, len(groups)):
                (na, va, ta), (nb, vb, tb) = groups[i], groups[j]
                d, near = cKDTree(va).query(vb)
                if not (d <= tol).any():
                    continue
                new = np.flatnonzero(d > tol)                 # b's vertices not in a
                index = near.copy()
                index[new] = len(va) + np.arange(len(new))
                groups[i] = (f"{na}+{nb}", np.vstack([va, vb[new]]),
                             np.vstack([ta, index[tb]]))
                del groups[j]
                merged = True
                break
            if merged:
                break
    return {name: RigidSurface(v, t) for name, v, t in groups}


def _jaw_motion(surfaces, surface, jaw, tol=1e-9):
    """(jaw, moving (p,)) for a (joined) rigid surface: its vertices that are the lower
    teeth's and not the upper teeth's; None without a jaw or such vertices."""
    if jaw is None or "lower_teeth" not in surfaces:
        return None
    v = np.asarray(surface.vertices, float)
    moving = cKDTree(surfaces["lower_teeth"].vertices).query(v)[0] <= tol
    if "upper_teeth" in surfaces:
        moving &= cKDTree(surfaces["upper_teeth"].vertices).query(v)[0] > tol
    return (jaw, moving) if moving.any() else None


def build_contact_terms(anatomy, lips=True, teeth=True, teeth_distance=3.0, rest_offset=True,
                        lip_penalty=None, jaw=None, **options):
    """The contact terms of an Anatomy: a RigidContact per rigid surface (surfaces that
    share a seam joined: joined_surfaces; named after the surface, with '_contact'; slaves: the movable
    nodes of the mesh boundary within teeth_distance (mm) of it at rest: the inner lip and
    cheek surfaces; rest_offset as RigidContact's) when teeth, a LipContact when lips
    (mirrored on the 'midsagittal' nodes of a half anatomy), with lip_penalty (N/mm^3)
    where given; options go to every term (penalty, smoothing). jaw (solver.face.jaw.Jaw):
    the lower teeth's vertices follow its pose (those that the upper teeth share, on a
    seam, stay with the upper: the lower sheet's first row stretches over the gap).
    """
    mesh, surfaces = anatomy.mesh, anatomy.contact_surfaces
    terms = []
    if teeth:
        nodes = np.setdiff1d(np.unique(mesh.boundary_faces()), mesh.node_sets.get("fixed", []))
        for name, surface in joined_surfaces(anatomy.rigid_surfaces).items():
            motion = _jaw_motion(anatomy.rigid_surfaces, surface, jaw)
            teeth = dict({"penalty": TEETH_PENALTY}, **options)
            terms.append(RigidContact(mesh, nodes_near(mesh, nodes, surface, teeth_distance),
                                      surface, name=f"{name}_contact",
                                      rest_offset=rest_offset, motion=motion, **teeth))
    if lips:
        mirror = mesh.node_sets["midsagittal"] if anatomy.half else None
        lip = dict(options, **({} if lip_penalty is None else {"penalty": lip_penalty}))
        terms.append(LipContact(mesh, surfaces["upper_lip"], surfaces["lower_lip"],
                                mirror_nodes=mirror, **lip))
    return terms
