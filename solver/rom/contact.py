r"""Reduced contact for the online step: the penalty contact terms' own kernels, called on
the few nodes they concern, their forces projected in one numba pass.

The contact terms (solver.face.terms.contact) assemble on full-size arrays; the reduced model
needs only their slave (and, for lip contact, master) nodes. Per term an adapter:

* RigidContact (lips and cheeks on the teeth): the term's kernel (rigid_contact, with
  the term's arguments) on the slave positions x_s = X_s + V_s q, with short candidate
  lists: at a reference position x_ref,i of slave i, d_i from the surface, the triangles
  within d_i + 2 delta. While the slave has moved by at most delta (its motion plus the
  surface's, when the jaw moves) the kernel finds the same nearest triangle, gap and force
  as the term; beyond, the lists are rebuilt (one brute-force numba pass; delta 0.5 mm in
  solver.rom.simulation, at least MOVING_DELTA on a surface that follows a moving jaw).
  Slaves are not skipped by distance: beyond a free edge the penalty is not a function of
  the distance alone.
* LipContact (two passes, candidate pairs fixed at rest by the term): the term's kernel
  (surface_contact) on the positions of the contact nodes, the master surface's normals
  refreshed on the rows the kernel reads (Normals.read); private copies of the pair work
  arrays.
* anything else: the term's assemble() on a full-size displacement filled at the
  contact nodes only (the generic, slower path; solver.rom.reduced does the same).

The jaw (set_pose): the contact nodes sit at X + L + V q (L the lifting,
solver.rom.lifting), and the lower teeth at the jaw's pose (RigidContact.move_to).

Each adapter adds V_b^T f_b (and V_b^T K_b V_b) of its active blocks (project_nodal) and
reports its normal contact force (N) and its active set (for the tangent's refresh).
tests/test_rom_online.py checks the adapters against the terms' assemble().

Why the candidate lists hold, and the jaw's bound: docs/method.md, section 'Reduced
contact'.
"""

import numpy as np

from solver.core.assembly import block_dofs
from solver.core.kernels.contact import (NO_PAIR_FREE, rigid_contact, surface_contact,
                                         surface_normals_part)
from solver.core.terms.base import State
from solver.face.terms.contact import pair_maps
from solver.rom.contact_kernels import (centroids_radii, fill_positions, mirror_normals,
                                        project_pairs,
                                        project_slaves, short_lists, slave_positions)
from solver.rom.online_kernels import project_nodal


def _deepest(gap):
    """-min(gap) over the finite gaps, 0 where none is negative."""
    g = gap[np.isfinite(gap)]
    return float(max(0.0, -g.min())) if g.size else 0.0


MOVING_DELTA = 1.0   # mm: the least delta of lists on a surface the jaw is moving


class _Rigid:
    def __init__(self, term, Vn, delta):
        self.term, self.base = term, float(delta)
        self.delta = self.base                 # the margin the current lists were built with
        self.slaves = np.asarray(term.slaves, dtype=np.int64)
        s = len(self.slaves)
        self.X = np.ascontiguousarray(term.x0)              # rest positions, offsets in
        self.Vs = np.ascontiguousarray(Vn[self.slaves])                    # (s, 3, r)
        tris = term.tris
        self.cen, self.rad = np.zeros((len(tris), 3)), np.zeros(len(tris))
        centroids_radii(term.vertices, tris, self.cen, self.rad)
        self.depth = float(term.search_radius)
        self.X0 = self.X
        self.pose = np.zeros(2)
        self.pose_ref = None               # the surface's pose when the lists were built
        if term.motion is not None:
            # a bound of the moving vertices' motion between two poses: |d theta| R + |d p|,
            # R their largest distance from the jaw's axis (solver.face.jaw: x along it)
            jaw, moving = term.motion
            r = term.rest_vertices[moving] - jaw.geometry.centre
            self.R = float(np.sqrt((r[:, 1:] ** 2).sum(axis=1).max())) if moving.any() else 0.0
        # the term's kernel arguments after `tri` (its free-edge fade and rim topology)
        self.extra = term.rim_args()
        self.ptr = np.zeros(s + 1, dtype=np.int64)
        self.cand = np.zeros(s * len(tris), dtype=np.int64)
        self.dist = np.zeros(s)
        self.x, self.x_ref = np.zeros((s, 3)), np.zeros((0, 3))
        self.all = np.arange(s)
        self.xs = np.zeros((s, 3))
        self.fe, self.ke = np.zeros((s, 3)), np.zeros((s, 3, 3))
        self.gap, self.force = np.zeros(s), np.zeros(s)
        self.tri = -np.ones(s, dtype=np.int64)
        self.kv = np.zeros((3, Vn.shape[2]))
        self._f0 = np.zeros(Vn.shape[2])

    def nodes(self):
        return self.slaves

    def set_pose(self, pose, L):
        """The jaw's pose (2,) and the lifting L (n, 3) of the coming evaluations."""
        self.pose = pose
        Ls = L[self.slaves]
        self.X = np.ascontiguousarray(self.X0 + Ls) if np.any(Ls) else self.X0

    def _follow(self):
        """A bound (mm) of the surface's vertices' motion since the lists were built."""
        if self.pose_ref is None:
            return 0.0
        d = self.pose - self.pose_ref
        return abs(d[0]) * (np.pi / 180.0) * self.R + abs(d[1])

    def _rebuild(self):
        """The lists at the current slave positions x, on the surface where it is."""
        t = self.term
        if t.motion is not None:
            # while the jaw moves its motion spends the margin too (|d theta| R + |d p|, R
            # about 100 mm): longer lists then cost less than rebuilding every few substeps
            moved = self.pose_ref is not None and not np.array_equal(self.pose, self.pose_ref)
            self.delta = max(self.base, MOVING_DELTA) if moved else self.base
            centroids_radii(t.vertices, t.tris, self.cen, self.rad)
            self.pose_ref = self.pose.copy()
        short_lists(self.x, self.cen, self.rad, t.vertices, t.tris, self.delta, self.depth,
                    self.ptr, self.cand, self.dist)
        self.x_ref = self.x.copy()

    def reset(self):
        self.x_ref = np.zeros((0, 3))                  # rebuild the lists at the next call
        self.pose_ref = None                           # at the base margin, as at the start

    def evaluate(self, q, x, need_k, fr, kr):
        t = self.term
        if t.motion is not None and not np.array_equal(t.pose, self.pose):
            t.move_to(self.pose)
        move = slave_positions(q, self.X, self.Vs, self.x_ref, self.all, self.x, self.xs)
        if not move + self._follow() <= self.delta:
            self._rebuild()
        # the slaves' tangents too (cheap): tangent() projects them without a new call
        rigid_contact(self.xs, t.k, t.vertices, t.tris, self.ptr, self.cand,
                      *t.normals.args(), t.search_radius, t.smoothing, True, self.fe, self.ke,
                      self.gap, self.force, self.tri, *self.extra)
        return project_slaves(self.Vs, self.fe, self.ke, self.gap, self.force, need_k, fr,
                              kr, self.kv)

    def penetration(self):
        """The deepest penetration (mm, >= 0) of the last evaluation's slaves."""
        return _deepest(self.gap)

    def tangent(self, kr):
        """kr += the reduced tangent of the last evaluation."""
        project_slaves(self.Vs, self.fe, self.ke, self.gap, self.force, True, self._f0,
                       kr, self.kv)


class _Lip:
    def __init__(self, term, Vn):
        self.term, self.Vn = term, Vn
        self.passes = [self._work(p) for p in term.passes]
        self.kv = np.zeros((12, Vn.shape[2]))
        self._f0 = np.zeros(Vn.shape[2])
        self.n = len(Vn)
        self.xe = np.zeros((self.n + len(term.virtual_nodes), 3))   # with the virtual vertices

    def _work(self, p):
        """The adapter's arrays of the term's pass p, for its current candidate pairs (the
        term replaces them when the full model re-picks them: evaluate then rebuilds)."""
        term, Vn = self.term, self.Vn
        nodes = np.asarray(p["nodes"], dtype=np.int64)
        npair = len(p["pair_tri"])
        nrm = term.normals[p["master"]]
        part = nrm.read(p["pair_tri"])            # the master rows the kernel reads
        return {"p": p, "src": p["pair_tri"], "nrm": nrm, "rows": part.rows,
                "mirror": (part.me[0].astype(np.int64), part.me[1].astype(np.int64),
                           np.asarray(part.mv, dtype=np.int64)),
                # the basis rows of the kernel's dofs (slave, triangle vertices)
                "Vb": np.ascontiguousarray(pair_maps(p["pair_weights"])
                                           @ Vn[nodes].reshape(npair, 15, -1)),
                "fe": np.zeros((npair, 12)), "ke": np.zeros((npair, 12, 12)),
                "active": -np.ones(len(p["slaves"]), dtype=np.int64),
                "kept": -np.ones(len(p["slaves"]), dtype=np.int64),
                "gap": np.zeros(len(p["slaves"])), "force": np.zeros(len(p["slaves"])),
                # the term's kernel arguments after `kept` (its candidate-boundary flags
                # and fade length), as its assemble() passes them
                "extra": (p["pair_free"] if "pair_free" in p else NO_PAIR_FREE,
                          float(getattr(term, "fade", 1.0)))}

    def nodes(self):
        # pair nodes and every node of the master surfaces (their edge and vertex
        # pseudo-normals involve the neighbouring triangles), the quads' corners
        real = [t[t < self.n] for t in (np.asarray(n.tris).ravel() for n in self.term.normals)]
        return np.concatenate([np.asarray(p["p"]["nodes"]).ravel() for p in self.passes]
                              + real + [np.asarray(self.term.virtual_nodes).ravel()])

    def evaluate(self, q, x, need_k, fr, kr):
        t = self.term
        total, sig = 0.0, 0
        x = t.extend(x, self.xe)
        for i, w in enumerate(self.passes):
            if w["p"]["pair_tri"] is not w["src"]:        # the term re-picked its pairs
                self.passes[i] = w = self._work(w["p"])
            p, nrm = w["p"], w["nrm"]
            # nrm.update(x, part) on the rows the kernel reads, the mirror part in numba
            surface_normals_part(x, nrm.tris, nrm.topo.nbr, *w["rows"], nrm.fn, nrm.en, nrm.vn)
            mirror_normals(nrm.en, w["mirror"][0], w["mirror"][1], nrm.vn, w["mirror"][2])
            surface_contact(x, p["slaves"], p["k"], nrm.tris, p["ptr"], p["pair_tri"],
                            *nrm.args(), t.depth, t.smoothing, True, w["fe"], w["ke"],
                            w["gap"], w["force"], w["active"], w["kept"], *w["extra"])
            f, h = project_pairs(w["Vb"], w["fe"], w["ke"], w["active"], w["force"], need_k,
                                 fr, kr, self.kv)
            total, sig = total + f, sig * 1000003 + h
        return total, sig

    def penetration(self):
        """The deepest penetration (mm, >= 0) of the last evaluation's slaves, both passes."""
        return max(_deepest(w["gap"]) for w in self.passes)

    def tangent(self, kr):
        """kr += the reduced tangent of the last evaluation."""
        for w in self.passes:
            project_pairs(w["Vb"], w["fe"], w["ke"], w["active"], w["force"], True, self._f0,
                          kr, self.kv)


class _Capture:
    """An Assembly stand-in for a term's assemble(): keeps its element blocks."""

    def __init__(self, need_k):
        self.need_k, self.energy, self.blocks = need_k, 0.0, []

    def add_block(self, block, fe, ke=None, rows=None):
        self.blocks.append((block, fe, ke, rows))


class _Generic:
    """Any contact term through its assemble() (full-size displacement, zero off its nodes)."""

    def __init__(self, term, V):
        self.term = term
        self.lam = 1.0
        self.bl = term.blocks()
        self.Vb = [np.ascontiguousarray(V[block_dofs(b)]) for b in self.bl]

    def nodes(self):
        return np.concatenate([np.asarray(b).ravel() for b in self.bl])

    def evaluate(self, q, x, need_k, fr, kr):
        cap = _Capture(need_k)
        u = x - self.term.mesh.nodes
        self.term.assemble(State(u, self.lam, 0.0, {}), cap, list(range(len(self.bl))))
        for block, fe, ke, rows in cap.blocks:
            Vb = self.Vb[block] if rows is None else self.Vb[block][rows]
            rows = np.arange(len(Vb))
            if len(Vb) == 0:
                continue
            fe = np.ascontiguousarray(fe.reshape(len(Vb), -1))
            ke = np.ascontiguousarray(ke) if ke is not None else \
                np.zeros((len(Vb), fe.shape[1], fe.shape[1]))
            Vb = np.ascontiguousarray(Vb.reshape(len(Vb), fe.shape[1], -1))
            project_nodal(Vb, fe, ke, rows, need_k and ke is not None, fr, kr)
        force = getattr(self.term, "force", np.zeros(0))
        self._last = (q, x)
        return float(getattr(self.term, "total_force", 0.0)), (np.asarray(force) > 0).tobytes()

    def tangent(self, kr):
        """kr += the reduced tangent at the last evaluation's state (a new assemble())."""
        q, x = self._last
        self.evaluate(q, x, True, np.zeros(kr.shape[0]), kr)


def _adapter(term, V, Vn, delta, generic):
    from solver.face.terms.contact import LipContact, RigidContact
    if not generic:
        try:
            if type(term) is RigidContact:
                return _Rigid(term, Vn, delta)
            if type(term) is LipContact:
                return _Lip(term, Vn)
        except (AttributeError, KeyError, TypeError):
            pass                              # a term that changed shape: the generic path
    return _Generic(term, V)


class ReducedContact:
    """The contact terms of a face, reduced. terms: contact terms (solver.face.terms.contact);
    V (3 n, r) the basis; delta (mm): slave motion before the rigid candidate lists are
    rebuilt; generic: every term through its assemble() (the reference path)."""

    def __init__(self, terms, V, n_nodes, delta=0.2, generic=False):
        self.r = V.shape[1]
        Vn = V.reshape(n_nodes, 3, self.r)
        self.adapters = [_adapter(t, V, Vn, delta, generic) for t in terms]
        nodes = [a.nodes() for a in self.adapters]
        if self.adapters and not self.fast:                    # the generic path: all
            nodes = [np.arange(n_nodes)]
        self.nodes = np.unique(np.concatenate(nodes)) if nodes else np.zeros(0, np.int64)
        self.Vc = np.ascontiguousarray(Vn[self.nodes])
        self.X = np.ascontiguousarray(terms[0].mesh.nodes) if terms else np.zeros((0, 3))
        self.X0 = self.X
        self.x = self.X.copy()                 # current positions at the contact nodes
        self.fr, self.kr = np.zeros(self.r), np.zeros((self.r, self.r))
        self.total_force, self.active = 0.0, tuple(0 for _ in self.adapters)

    def reset(self):
        """Forget the cached candidate lists (rebuilt at the next evaluation)."""
        for a in self.adapters:
            if hasattr(a, "reset"):
                a.reset()

    def set_pose(self, pose, L, lam=1.0):
        """The jaw's pose (2,), the lifting L (n, 3) at it and the caller's load factor
        lam there (the generic path's terms move their surfaces by lam)."""
        self.X = np.ascontiguousarray(self.X0 + L) if np.any(L) else self.X0
        for a in self.adapters:
            if isinstance(a, _Rigid):
                a.set_pose(np.array(pose, dtype=np.float64), L)
            elif isinstance(a, _Generic):
                a.lam = float(lam)

    @property
    def fast(self):
        """True where every term has a fast adapter."""
        return not any(isinstance(a, _Generic) for a in self.adapters)

    @property
    def penetration(self):
        """The deepest lip/lip or lip/teeth penetration (mm) of the last evaluate(), as the
        terms' kernels measure it (the generic path's terms: not measured, 0)."""
        return max((a.penetration() for a in self.adapters if hasattr(a, "penetration")),
                   default=0.0)

    def tangent(self, i):
        """(r, r) the tangent of term i at the state of the last evaluate() (a new array;
        the fast adapters keep their slaves' tangents from that evaluation)."""
        kr = np.zeros((self.r, self.r))
        self.adapters[i].tangent(kr)
        return kr

    def evaluate(self, q, need_k, out=None):
        """Adds the reduced contact force at q to out (r,) (default: a work array, zeroed
        first, returned with K_r (r, r) or None; valid to the next call). Sets total_force
        (N) and active (a signature per term of its active slaves or pairs: equal sets,
        equal signatures)."""
        fr = self.fr if out is None else out
        if out is None:
            fr[:] = 0.0
        if need_k:
            self.kr[:, :] = 0.0
        if self.adapters:
            fill_positions(q, self.X, self.Vc, self.nodes, self.x)
            total, active = 0.0, []
            for a in self.adapters:
                f, sig = a.evaluate(q, self.x, need_k, fr, self.kr)
                total += f
                active.append(sig)
            self.total_force, self.active = total, tuple(active)
        return fr, (self.kr if need_k else None)
