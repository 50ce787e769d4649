"""Lip on lip: node-on-surface penalty contact between two deformable lip surfaces, both
ways (LipContact)."""

import numpy as np
from scipy.spatial import cKDTree

from solver.core.errors import ParameterError
from solver.core.kernels.contact import (extend_points, min_facing, NO_PAIR_FREE,
                                         pair_distances, surface_contact)
from solver.core.kernels.contact_linear import surface_linear_gaps
from solver.core.terms.base import pack_parts, Term, unpack_parts
from solver.face.terms.contact.base import (check_penalty, ContactReport, EDGE_FADE,
                                            FACING_TOLERANCE, PENALTY)
from solver.face.terms.contact.surfaces import (centred_triangles, incidence, Normals,
                                                pair_maps, tributary_areas)
from solver.face.terms.contact.search import candidate_lists


class LipContact(ContactReport, Term):
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
        check_penalty(penalty, smoothing)
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
        self.normals = [Normals(t, first, ext).update(x0) for t in surf]
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
        ptr, ti = candidate_lists(cKDTree(cen), x[slaves], radius + reach)
        si = np.repeat(np.arange(len(slaves)), np.diff(ptr))
        st = self.normals[s].tris
        sn = self.normals[s].fn                               # the slave surface's faces
        d2 = np.empty(len(ti))
        pair_distances(x[slaves[si]], x, tris, ti, d2)
        ok = d2 <= radius ** 2
        if facing_only:
            ahead = ((x[slaves[si]] - x[tris[ti, 0]]) * fn[ti]).sum(axis=1)  # plane distance
            inc_p, inc_t = incidence(st, len(x))
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
