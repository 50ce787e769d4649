"""Interpenetration measured outside every model: Probe and its geometry.

The point-triangle distance here is a second, independent implementation of the one in
the model's contact kernel (solver.core.kernels.contact), on purpose: contact is measured
outside the model, and a probe that shared the model's kernel would check the model
against itself.

Probe measures, for any state, the deepest lip-surface node inside tissue it does not
belong to (inside_bricks: Newton on the trilinear map, the winding number where Newton
finds no root; depth: the distance to the nearest lip face, each bilinear face sampled by
face_sampling into FACE_DIVISIONS^2 sub-quads) and the deepest penetration behind the
rigid teeth (RigidContact terms that belong to no model, searching PROBE_DEPTH mm deep).
The runner (runner.check_state) holds both to the contact tolerance where the scene's
contact is on.
"""

import numpy as np

from solver.core.assembly import Assembly, Pattern
from solver.core.terms.base import State

PROBE_DEPTH = 5.0           # mm: deepest lip-into-teeth penetration the probe sees
FACE_DIVISIONS = 16         # sub-quads per edge of a lip face, for the probe's depth


def point_triangle_distance(p, a, b, c):
    """(t,) distances of a point p (3,) to triangles with corners a, b, c (t, 3) each
    (Ericson, Real-Time Collision Detection 5.1.5, over all triangles at once)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp, cp = p - b, p - c
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v, w = vb / denom, vc / denom                               # inside the face
        q = a + v[:, None] * ab + w[:, None] * ac
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    cases = [  # (region mask, closest point), the first that holds wins
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[:, None] * ab),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[:, None] * ac),
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + t_bc[:, None] * (c - b)),
    ]
    done = np.zeros(len(a), dtype=bool)
    for mask, point in cases:
        take = mask & ~done
        q[take] = point[take]
        done |= take
    return np.linalg.norm(p - q, axis=1)


HEX_FACES = ((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7))


def brick_winding(xe, p):
    """The winding number of the brick xe (8, 3) (ANSYS node order) around the point p
    (3,): 1 inside, 0 outside; each face split into four triangles around its centroid
    (the solid angles of Van Oosterom and Strackee)."""
    total = 0.0
    for f in HEX_FACES:
        q = xe[list(f)] - p
        c = q.mean(axis=0)
        lc = np.linalg.norm(c)
        for i in range(4):
            a, b = q[i], q[(i + 1) % 4]
            la, lb = np.linalg.norm(a), np.linalg.norm(b)
            num = a @ np.cross(b, c)
            den = la * lb * lc + (a @ b) * lc + (b @ c) * la + (c @ a) * lb
            total += 2.0 * np.arctan2(num, den)
    return total / (4.0 * np.pi)


def inside_bricks(xe, p):
    """(m,) whether each point p (m, 3) lies inside its brick xe (m, 8, 3): natural
    coordinates within 1 - 1e-3 by Newton on the trilinear map; where Newton finds no
    root (a residual above 1e-7 mm: it can stop, clipped, inside the box), the brick's
    winding number decides (brick_winding)."""
    from solver.core.element import shape_functions, shape_gradients
    xi = np.zeros((len(p), 3))
    ok = np.ones(len(p), dtype=bool)
    for _ in range(25):
        r = np.einsum("pa,pai->pi", shape_functions(xi), xe) - p
        J = np.einsum("pai,paj->pij", xe, shape_gradients(xi))
        ok &= np.abs(np.linalg.det(J)) > 1e-12
        J[~ok] = np.eye(3)
        step = np.linalg.solve(J, -r[..., None])[..., 0]
        xi = np.clip(xi + step, -3.0, 3.0)
        if np.abs(step[ok]).max(initial=0.0) < 1e-10:
            break
    r = np.einsum("pa,pai->pi", shape_functions(xi), xe) - p
    solved = ok & (np.linalg.norm(r, axis=1) < 1e-7)
    hit = solved & np.all(np.abs(xi) < 1.0 - 1e-3, axis=1)
    for k in np.flatnonzero(~solved):
        hit[k] = brick_winding(xe[k], p[k]) > 0.5
    return hit


def face_sampling(n):
    """A bilinear face sampled by n x n sub-quads: weights (g, 4) of the (n + 1)^2 grid
    points over the face's corners, and the sub-quads' triangles (2 n^2, 3) over them."""
    g = np.linspace(-1.0, 1.0, n + 1)
    s, t = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    w = 0.25 * np.column_stack([(1 - s) * (1 - t), (1 + s) * (1 - t), (1 + s) * (1 + t),
                                (1 - s) * (1 + t)])
    k = np.arange(n + 1)[:, None] * (n + 1) + np.arange(n + 1)[None]
    a, b, c, d = k[:-1, :-1].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel(), k[:-1, 1:].ravel()
    return w, np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


class Probe:
    """Interpenetration of any state, measured outside every model.

    Lips: a node of a lip contact surface that lies inside a brick it does not belong to
    (natural coordinates within 1 - 1e-3, by Newton on the trilinear map; where Newton
    finds no root, the brick's winding number around the node) has entered
    tissue (the other lip, or its own lip folded over); its depth is its distance to the
    nearest lip-surface face it is not a corner of (the bilinear face, sampled by
    FACE_DIVISIONS^2 sub-quads: within a few thousandths of its warp). This sees what a contact term
    cannot: a node passing through triangles outside its candidate pairs. Teeth: the
    signed distances to the rigid teeth sheets of the nodes the model's teeth contact
    would hold (solver.face.terms.contact.build_contact_terms), by RigidContact terms that are
    in no model and search PROBE_DEPTH mm deep; with jaw (solver.face.jaw.Jaw, the model's),
    the lower teeth at its pose."""

    def __init__(self, anatomy, depth=PROBE_DEPTH, jaw=None):
        from solver.face.terms.contact import build_contact_terms
        mesh = anatomy.mesh
        self.mesh = mesh
        surf = anatomy.contact_surfaces
        faces = [f for k, f in surf.items() if k in ("upper_lip", "lower_lip")]
        self.nodes = np.unique(np.concatenate([f.ravel() for f in faces])) if faces else \
            np.zeros(0, dtype=np.int64)
        quads = [np.asarray(f) if np.asarray(f).shape[1] == 4 else
                 np.asarray(f)[:, [0, 1, 2, 2]] for f in faces]
        self.faces = np.vstack(quads) if faces else np.zeros((0, 4), dtype=np.int64)
        self._w, self._sub = face_sampling(FACE_DIVISIONS)
        self.teeth = []
        if anatomy.rigid_surfaces and surf:
            self.teeth = build_contact_terms(anatomy, lips=False, teeth=True,
                                             search_radius=depth, jaw=jaw)
        self._patterns = {id(t): Pattern(3 * mesh.n_nodes, t.blocks()) for t in self.teeth}
        self.inside = []          # (node, brick, depth) of the last lip measure

    def lip_overlap(self, u):
        """The deepest lip-surface node inside tissue it does not belong to (mm, 0 if
        none); the offenders in self.inside."""
        mesh = self.mesh
        self.inside = []
        if not len(self.nodes):
            return 0.0
        x = mesh.nodes + u
        xb = x[mesh.bricks]                                        # (m, 8, 3)
        lo, hi = xb.min(axis=1), xb.max(axis=1)
        p = x[self.nodes]
        near = np.all((lo[None] <= p[:, None] + 1e-9) & (p[:, None] <= hi[None] + 1e-9), axis=2)
        near &= ~(mesh.bricks[None, :, :] == self.nodes[:, None, None]).any(axis=2)
        ni, be = np.nonzero(near)
        if not len(ni):
            return 0.0
        hit = inside_bricks(xb[be], p[ni])
        worst = 0.0
        for k in np.flatnonzero(hit):
            node = int(self.nodes[ni[k]])
            depth = self.face_distance(x, node)
            self.inside.append((node, int(be[k]), depth))
            worst = max(worst, depth)
        return worst

    def face_distance(self, x, node):
        """The distance (mm) of node to the lip surfaces' bilinear faces it is not a
        corner of, at positions x (n, 3) (each face sampled by FACE_DIVISIONS^2
        sub-quads, two triangles each); only faces whose corners come within the
        nearest corner's distance plus the face's size are sampled."""
        f = self.faces[~(self.faces == node).any(axis=1)]
        xf = x[f]                                                      # (f, 4, 3)
        size = np.linalg.norm(xf - xf.mean(axis=1)[:, None], axis=2).max(axis=1)
        corner = np.linalg.norm(xf - x[node], axis=2).min(axis=1)
        f, xf = f[corner - size <= (corner + size).min()], xf[corner - size <= (corner + size).min()]
        pts = np.einsum("ga,fai->fgi", self._w, xf)                   # (f, g, 3)
        tri = pts[:, self._sub].reshape(-1, 3, 3)
        area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        tri = tri[area > 1e-12]                         # a degenerate quad's collapsed rows
        return float(point_triangle_distance(x[node], tri[:, 0], tri[:, 1], tri[:, 2]).min())

    def teeth_penetration(self, u):
        """The deepest lip-into-teeth penetration (mm, >= 0)."""
        worst = 0.0
        for t in self.teeth:
            pattern = self._patterns[id(t)]
            t.assemble(State(u), Assembly(pattern, False), list(range(len(pattern.dofs))))
            worst = max(worst, t.max_penetration)
        return worst

    def penetrations(self, u):
        """(lips, teeth) deepest penetrations (mm, >= 0) at displacements u (n, 3)."""
        u = np.asarray(u, dtype=float).reshape(-1, 3)
        return self.lip_overlap(u), self.teeth_penetration(u)
