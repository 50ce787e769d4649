"""Lips and cheeks on the rigid teeth: node-on-surface penalty contact against a moving
rigid sheet (RigidContact)."""

import numpy as np
from scipy.spatial import cKDTree

from solver.core.errors import ParameterError
from solver.core.kernels.contact import rest_offsets, rigid_contact, signed_gaps
from solver.core.kernels.contact_linear import rigid_linear_gaps
from solver.core.terms.base import Term
from solver.face.terms.contact.base import check_penalty, ContactReport, EDGE_FADE, PENALTY
from solver.face.terms.contact.surfaces import Normals
from solver.face.terms.contact.search import (candidate_lists, facing_areas, nearest_lists,
                                              tissue_points)


class RigidContact(ContactReport, Term):
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
        check_penalty(penalty, smoothing)
        if not fade >= 0:
            raise ParameterError(f"{name}: fade = {fade!r} must be >= 0 (mm)")
        self.name, self.mesh, self.smoothing = name, mesh, float(smoothing)
        self.fade = float(fade)
        slaves = np.asarray(slave_nodes, dtype=np.int64).ravel()
        self.vertices = np.ascontiguousarray(surface.vertices, dtype=np.float64)
        tris = np.ascontiguousarray(surface.triangles, dtype=np.int64)
        self.search_radius, self.margin = float(search_radius), float(margin)
        vote = self._rest_gaps(tris, tissue_points(mesh, slaves))
        sided = np.isfinite(vote) & (vote != 0)
        if not sided.any():
            raise ParameterError(f"{name}: no slave node faces the surface at rest")
        self.flipped = bool((vote[sided] < 0).sum() > (vote[sided] > 0).sum())
        if self.flipped:
            tris = np.ascontiguousarray(tris[:, ::-1])
        self.tris = tris
        self.normals = Normals(tris, len(self.vertices)).update(self.vertices)
        area = facing_areas(mesh, slaves, self.vertices, tris, self.normals.fn) \
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
        normals = Normals(tris, len(self.vertices)).update(self.vertices)
        ptr, cand = nearest_lists(self.vertices, tris, x)
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
                            *candidate_lists(self._tree, x, self.search_radius + self._reach
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
