"""Contact surfaces: lip quads cut into centred triangles, node areas, the surface
topology (free edges and vertices), pseudo-normals, and rigid surfaces joined at their
seams."""

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from solver.core.errors import ParameterError
from solver.core.kernels.contact import surface_normals, surface_normals_part


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


class Topology:
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
class NormalsPart:
    """Rows of a Normals update: rows, surface_normals_part's (faces, ring, verts, mark,
    edges); me, mv: the mirror edges (t, j) and vertices among them."""
    rows: tuple
    me: tuple
    mv: np.ndarray


class Normals:
    """Face, edge and vertex (pseudo-)normals of a triangle surface, refreshed by update;
    on mirror edges and vertices (see Topology) the normals of the mirrored surface
    (x -> -x) are included: their x component vanishes."""

    def __init__(self, tris, p, mirror=None):
        self.tris = tris
        self.verts = np.unique(tris)
        self.topo = Topology(tris, p, mirror)
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
        return NormalsPart(
            rows=(np.ascontiguousarray(faces, dtype=np.int64),
                  np.ascontiguousarray(ring, dtype=np.int64),
                  np.ascontiguousarray(verts, dtype=np.int64), mark,
                  np.ascontiguousarray(edges, dtype=np.int64)),
            me=(self._me[0][in_edges], self._me[1][in_edges]),
            mv=self._mv[mark[self._mv]])

    def args(self):
        """The kernels' (fn, en, vn, free_edge, free_vertex)."""
        return self.fn, self.en, self.vn, self.topo.free_edge, self.topo.free_vertex


def incidence(tris, n):
    """CSR lists (ptr (n + 1,), triangle ids) of the triangles at each of n nodes."""
    node = tris.ravel()
    order = np.argsort(node, kind="stable")
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(node, minlength=n), out=ptr[1:])
    return ptr, order // 3


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


def jaw_motion(surfaces, surface, jaw, tol=1e-9):
    """(jaw, moving (p,)) for a (joined) rigid surface: its vertices that are the lower
    teeth's and not the upper teeth's; None without a jaw or such vertices."""
    if jaw is None or "lower_teeth" not in surfaces:
        return None
    v = np.asarray(surface.vertices, float)
    moving = cKDTree(surfaces["lower_teeth"].vertices).query(v)[0] <= tol
    if "upper_teeth" in surfaces:
        moving &= cKDTree(surfaces["upper_teeth"].vertices).query(v)[0] > tol
    return (jaw, moving) if moving.any() else None
