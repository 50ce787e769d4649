"""Frictionless penalty contact: finite-difference tangents, a block on a rigid plane, two
blocks pressed together, sliding on an incline, the lips on the teeth of the reference face.
"""


import numpy as np
import pytest

import solver
from solver.face.anatomy.base import RigidSurface
from solver.core.assembly import Assembly, Pattern
from solver.core.kernels.contact import FACE, VERTEX, boundary_penalty, nearest, penalty_law
from solver.core.meshgen import box
from solver.core.terms.base import State
from solver.face.terms.contact import (PENALTY, LipContact, RigidContact,
                                       build_contact_terms, nodes_near, tributary_areas)
from solver.face.anatomy.reference import reference_face_dir

STIFF = solver.MooneyRivlin(c10=0.05, c20=0.0, d=0.04)      # 20 x the face's tissue, MPa
DATA = reference_face_dir()


def grid_surface(n, size, height=lambda x, y: 0.0 * x, rotation=np.eye(3)):
    """A triangulated square [-size/2, size/2]^2 with z = height(x, y), rotated; the
    triangles' normals point to +z (before the rotation)."""
    g = np.linspace(-size / 2, size / 2, n + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), height(X.ravel(), Y.ravel())]) @ rotation.T
    nid = np.arange(len(V)).reshape(n + 1, n + 1)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    T = np.vstack([np.column_stack([nid[i, j], nid[i + 1, j], nid[i + 1, j + 1]]),
                   np.column_stack([nid[i, j], nid[i + 1, j + 1], nid[i, j + 1]])])
    return RigidSurface(V, T)


class Runner:
    """Assemblies of one term alone over n nodes."""

    def __init__(self, term, n):
        self.term = term
        self.pattern = Pattern(3 * n, term.blocks())

    def __call__(self, u, need_k=True):
        asm = Assembly(self.pattern, need_k)
        self.term.assemble(State(np.asarray(u, dtype=float).reshape(-1, 3)), asm,
                           list(range(len(self.pattern.dofs))))
        return asm


def fd_derivatives(run, u, K, r, h=1e-6):
    """Central differences at u (n, 3), over the dofs where the tangent K or the residual
    r is nonzero, of the residual (Kfd) and of the energy (rfd) of the Runner run, which
    is left at u."""
    Kfd, rfd = np.zeros_like(K), np.zeros_like(r)
    for j in np.flatnonzero(np.abs(K).sum(axis=0) + np.abs(r) > 0):
        up, um = u.ravel().copy(), u.ravel().copy()
        up[j] += h
        um[j] -= h
        ap, am = run(up, False), run(um, False)
        Kfd[:, j] = (ap.residual - am.residual) / (2 * h)
        rfd[j] = (ap.energy - am.energy) / (2 * h)
    run(u)
    return Kfd, rfd


def fd_errors(term, u, h=1e-6, symmetric_part=False):
    """Relative errors of the tangent against central differences of the residual (their
    symmetric part if symmetric_part), and of the residual against central differences
    of the energy, at u (n, 3)."""
    run = Runner(term, len(u))
    asm = run(u)
    K, r = asm.matrix().toarray(), asm.residual
    Kfd, rfd = fd_derivatives(run, u, K, r, h)
    if symmetric_part:
        Kfd = 0.5 * (Kfd + Kfd.T)
    return np.abs(K - Kfd).max() / np.abs(K).max(), np.abs(r - rfd).max() / np.abs(r).max()


def two_blocks(gap=0.0, rng=None, jitter=0.0):
    """Block A (8 x 8 x 3 mm, top at z = 0) under a smaller block B (5 x 5 x 3 mm, 4 x 4
    bricks against A's 3 x 3, offset), B's bottom at z = gap. Returns the mesh, the node ids
    of A and of B, and the closed boundary surfaces of A and B (outward quads)."""
    a = box(3, 3, 2, (8.0, 8.0, 3.0), origin=(-4.0, -4.0, -3.0))
    b = box(4, 4, 2, (5.0, 5.0, 3.0), origin=(-2.4, -2.6, gap))
    nodes = np.vstack([a.nodes, b.nodes])
    if jitter:
        nodes += rng.uniform(-jitter, jitter, nodes.shape)
    sets = {f"A_{k}": v for k, v in a.node_sets.items()}
    sets.update({f"B_{k}": v + a.n_nodes for k, v in b.node_sets.items()})
    mesh = solver.Mesh(nodes, np.vstack([a.bricks, b.bricks + a.n_nodes]), node_sets=sets)
    ida, idb = np.arange(a.n_nodes), np.arange(a.n_nodes, mesh.n_nodes)
    faces = mesh.boundary_faces()
    in_a = np.isin(faces, ida).all(axis=1)
    return mesh, ida, idb, faces[in_a], faces[~in_a]


# ------------------------------------------------------------------ tangents (FD)

@pytest.mark.parametrize("smoothing", [0.0, 0.2])
def test_rigid_tangent_matches_finite_differences_on_faces_edges_and_vertices(rng, smoothing):
    # a pyramid pit z = 0.2 (|x| + |y|): creases along x = 0 and y = 0 (concave edges),
    # its apex a concave vertex; the block's bottom nodes sit over the apex, the creases
    # and the flat faces
    pit = grid_surface(4, 12.0, lambda x, y: 0.2 * (np.abs(x) + np.abs(y)))
    mesh = box(2, 2, 1, (6.0, 6.0, 2.0), origin=(-3.0, -3.0, 1.3))
    term = RigidContact(mesh, mesh.node_sets["zmin"], pit, smoothing=smoothing)
    u = rng.normal(0.0, 0.05, (mesh.n_nodes, 3))
    u[:, 2] -= 1.6
    err_k, err_r = fd_errors(term, u)
    assert term.n_active == 9 and not term.flipped
    regions = set()
    w = np.empty(3)
    for i, node in enumerate(term.slaves):
        regions.add(nearest(mesh.nodes[node] + u[node], pit.vertices, pit.triangles,
                            term.tri[i:i + 1], w, np.empty(3))[1])
    assert FACE in regions and regions & {1, 2, 3} and max(regions) >= VERTEX
    if smoothing:            # beyond the smoothing: the tangent is exact on edges too
        assert (-term.gap > smoothing).all()
    assert err_k < 1e-5 and err_r < 1e-5


@pytest.mark.parametrize("smoothing", [0.0, 0.05])
def test_lip_tangent_matches_finite_differences_with_master_rotation(rng, smoothing):
    mesh, ida, idb, fa, fb = two_blocks(rng=rng, jitter=0.15)   # warped master triangles
    term = LipContact(mesh, fb, fa, smoothing=smoothing, fade=1e-3)   # no rim in play
    u = rng.normal(0.0, 0.05, (mesh.n_nodes, 3))
    u[idb, 2] -= 0.4
    err_k, err_r = fd_errors(term, u)
    assert term.n_active >= 10
    assert all((q["active"] >= 0).any() for q in term.passes)  # both passes engaged
    # the master-side forces balance the slave-side ones, pair by pair
    np.testing.assert_allclose(term.nodal_force.sum(axis=0), 0.0, atol=1e-12)
    assert err_k < 1e-5 and err_r < 1e-5


@pytest.mark.parametrize("divisions, share", [(1, 8), (2, 32)])
def test_centred_triangles_stay_within_a_share_of_a_warped_quads_face(divisions, share):
    """A twisted quad z = h s t over the square [-1, 1]^2 (its diagonals' midpoints 2 h
    apart: the warp): the four triangles around its centre (centred_triangles) stay
    within warp / 8 of the bilinear face, the 16 of the 2 x 2 subdivision within
    warp / 32, a split along one diagonal within warp / 2; each triangle's vertices are
    its weights times the corners, and the virtual vertices lie on the bilinear face."""
    from solver.face.terms.contact import centred_triangles
    h = 0.3
    corners = np.array([[-1.0, -1.0, h], [1.0, -1.0, -h], [1.0, 1.0, h], [-1.0, 1.0, -h]])
    tris, vn, vw, quad, weights = centred_triangles(np.array([[0, 1, 2, 3]]), 4, divisions)
    x = np.vstack([corners, np.einsum("cb,cbi->ci", vw, corners[vn])])
    assert len(tris) == 4 * divisions ** 2
    np.testing.assert_allclose(np.einsum("tab,tbi->tai", weights, corners[quad]), x[tris])
    np.testing.assert_allclose(x[4:, 2], h * x[4:, 0] * x[4:, 1], atol=1e-12)

    def deviation(triangles):
        worst = 0.0
        for a, b, c in x[triangles] if triangles.ndim == 2 else triangles:
            for u in np.linspace(0.0, 1.0, 41):
                for v in np.linspace(0.0, 1.0 - u, 41):
                    p = u * a + v * b + (1.0 - u - v) * c
                    worst = max(worst, abs(p[2] - h * p[0] * p[1]))
        return worst

    warp = 2 * h
    assert deviation(tris) == pytest.approx(warp / share, rel=1e-3)
    split = np.array([[0, 1, 2], [0, 2, 3]])
    assert deviation(split) == pytest.approx(warp / 2, rel=1e-3)


def test_an_ansys_faces_lip_facets_become_the_faces_of_its_bricks():
    """The facets of an ANSYS lip surface split brick faces along a diagonal; the reader
    pairs them back into the brick faces (in the triangles' winding), so that the lip
    contact follows the bilinear faces (see the test above). A facet that splits no brick
    face, or whose partner is wound the other way, stays a triangle (a, b, c, c)."""
    from solver.face.anatomy.ansys import _brick_faces
    mesh = box(2, 1, 1)
    top = [int(i) for i in mesh.node_sets["zmax"]]
    x = mesh.nodes
    quad = sorted(top, key=lambda i: (x[i, 0], x[i, 1]))[:4]          # the left brick's top
    a, b, c, d = quad[0], quad[2], quad[3], quad[1]                  # counter-clockwise from +z
    right = [i for i in top if i not in quad]
    e = right[0]
    tris = np.array([[a, b, c], [a, c, d],               # one brick face, either diagonal
                     [b, e, c],                           # a facet of no brick face
                     [d, c, right[1]]])
    faces = _brick_faces(tris, mesh)
    assert faces.tolist()[0] in ([a, b, c, d], [b, c, d, a], [c, d, a, b], [d, a, b, c])
    assert faces.tolist()[1:] == [[b, e, c, c], [d, c, right[1], right[1]]]
    flipped = _brick_faces(np.array([[a, b, c], [a, d, c]]), mesh)    # inconsistent winding
    assert flipped.tolist() == [[a, b, c, c], [a, d, c, c]]


def test_subdivided_faces_share_their_edge_midpoints():
    """Two quads and a triangle (a degenerate quad) sharing edges, at divisions 2: one
    midpoint vertex per shared edge, so that the only free edges are the outline's (16 +
    16 + 4 triangles; 9 distinct edges, 2 of them shared: an outline of 7, halved)."""
    from solver.face.terms.contact.surfaces import Topology, centred_triangles
    faces = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [2, 6, 5, 5]])
    tris, vn, vw, _, _ = centred_triangles(faces, 7, 2)
    assert len(tris) == 36
    mids = [v for v in range(len(vn)) if (vw[v] == [0.5, 0.5, 0.0, 0.0]).all()]
    assert len(mids) == 9
    topo = Topology(tris, 7 + len(vn))
    assert topo.free_edge.sum() == 2 * 7


def test_partial_normal_updates_equal_the_whole_one(rng):
    """Normals.changed(moved): after a motion of the vertices `moved` only, its update
    leaves every row (face, edge, vertex normals) as the whole update does, bit for bit;
    Normals.read(tris): after a motion of every vertex, the rows of those triangles (their
    faces, edges and vertices) are the whole update's. On a curved sheet with a mirror
    plane (x = -2: a half model's), whose rows are renormalised too."""
    from solver.face.terms.contact.surfaces import Normals
    s = grid_surface(8, 4.0, height=lambda x, y: 0.2 * x * x - 0.1 * x * y)
    tris, x0 = np.asarray(s.triangles), np.asarray(s.vertices, dtype=float)
    x0 = x0 - [x0[:, 0].min(), 0.0, 0.0]                 # the plane x = 0 on an edge
    mirror = np.isclose(x0[:, 0], 0.0)
    moved = ((x0[:, 0] > 2.2) & (x0[:, 1] < 0.5)) | (mirror & (x0[:, 1] > 1.0))
    x1 = x0.copy()
    x1[moved] += 0.3 * rng.standard_normal((moved.sum(), 3))
    x1[mirror, 0] = 0.0                                    # mirror vertices stay on it
    whole = Normals(tris, len(x0), mirror).update(x1)
    part = Normals(tris, len(x0), mirror).update(x0)
    assert not np.array_equal(part.fn, whole.fn)
    rows = part.changed(moved)
    assert 0 < len(rows.rows[0]) < len(tris)               # a part, not all of it
    assert len(rows.mv) and len(rows.me[0])                # with mirror rows
    part.update(x1, rows)
    for a, b in zip(part.args()[:3], whole.args()[:3]):
        assert np.array_equal(a, b)
    x2 = x0 + 0.2 * rng.standard_normal(x0.shape)
    x2[mirror, 0] = 0.0
    whole.update(x2)
    read = part.read(np.array([0, 5, 7, 64]))
    part.update(x2, read)
    faces, _, verts, _, edges = read.rows
    assert np.isin([0, 5, 7, 64], edges).all() and mirror[verts].any()
    assert np.array_equal(part.fn[faces], whole.fn[faces])
    assert np.array_equal(part.en[edges], whole.en[edges])
    assert np.array_equal(part.vn[verts], whole.vn[verts])
    assert not np.array_equal(part.fn, whole.fn)           # the other rows were left


def test_setting_the_penalty_scales_every_contact_force(rng):
    """The penalty knob (benchmarks/fast_path.py --set contact.penalty=P) rescales the
    stiffness of every slave, in both passes of the lips; the gaps stay."""
    mesh, ida, idb, fa, fb = two_blocks(rng=rng, jitter=0.15)
    u = rng.normal(0.0, 0.05, (mesh.n_nodes, 3))
    u[idb, 2] -= 0.4
    pit = grid_surface(4, 12.0, lambda x, y: 0.2 * (np.abs(x) + np.abs(y)))
    block = box(2, 2, 1, (6.0, 6.0, 2.0), origin=(-3.0, -3.0, 1.3))
    v = rng.normal(0.0, 0.05, (block.n_nodes, 3))
    v[:, 2] -= 1.6
    for term, w in ((LipContact(mesh, fb, fa), u),
                    (RigidContact(block, block.node_sets["zmin"], pit), v)):
        run = Runner(term, len(w))
        before = run(w).residual
        gap = term.gap.copy()
        term.penalty = 0.25 * PENALTY
        assert term.penalty == 0.25 * PENALTY
        np.testing.assert_allclose(run(w).residual, 0.25 * before, atol=1e-15)
        np.testing.assert_array_equal(term.gap, gap)
        with pytest.raises(solver.ParameterError, match="penalty"):
            term.penalty = -1.0
        assert term.penalty == 0.25 * PENALTY


@pytest.mark.parametrize("lift", [-0.03, 0.03])
def test_smoothed_law_is_consistent_on_both_sides_of_the_surface(rng, lift):
    """With smoothing s, nodes within s of a face (in front or behind) carry force and
    stiffness, from the exact derivatives of the smoothed energy; at s = 0 the nodes in
    front carry none."""
    s = 0.1
    plane = grid_surface(5, 20.0)
    mesh = box(2, 2, 1, (4.0, 4.0, 2.0), origin=(-2.0, -2.0, 0.0))
    u = rng.normal(0.0, 0.005, (mesh.n_nodes, 3))
    u[:, 2] += lift
    # the nodes rest on the plane, where the smoothed law pushes: no rest offset here
    term = RigidContact(mesh, mesh.node_sets["zmin"], plane, smoothing=s, rest_offset=False)
    err_k, err_r = fd_errors(term, u)
    assert (np.abs(term.gap) < s).all() and (term.force > 0).all()
    assert err_k < 1e-5 and err_r < 1e-5
    pure = RigidContact(mesh, mesh.node_sets["zmin"], plane)
    Runner(pure, len(u))(u)
    assert (pure.force > 0).any() == (lift < 0)


def test_smoothed_lip_law_is_consistent_before_the_lips_touch(rng):
    """Two blocks 0.03 mm apart with smoothing 0.1 mm: both passes push before contact,
    over the deformable masters' faces, with the exact tangent (master rotation included)."""
    mesh, ida, idb, fa, fb = two_blocks(gap=0.03)
    term = LipContact(mesh, fb, fa, smoothing=0.1)
    u = rng.normal(0.0, 0.003, (mesh.n_nodes, 3))
    err_k, err_r = fd_errors(term, u)
    touching = term.force > 0
    assert touching.sum() >= 10 and (term.gap[touching] > 0).all()
    assert all((q["active"] >= 0).any() for q in term.passes)
    np.testing.assert_allclose(term.nodal_force.sum(axis=0), 0.0, atol=1e-12)
    assert err_k < 1e-5 and err_r < 1e-5


@pytest.mark.parametrize("smoothing", [0.0, 0.02])
def test_faded_penalty_beyond_a_free_edge_has_exact_derivatives(rng, smoothing):
    """E = psi(a) phi(l / L) of a point beyond a free edge (solver.core.kernels.contact.
    boundary_penalty): its gradient and Hessian in d against central differences, over
    the whole fade band and depths on both sides of the smoothing."""
    def energy(d, m):
        g, H = np.empty(3), np.empty((3, 3))
        return boundary_penalty(d, m, 3.0, smoothing, 0.5, True, g, H)[0], g, H

    h, checked = 1e-6, 0
    for _ in range(40):
        m = rng.normal(size=3)
        m /= np.linalg.norm(m)
        t = np.cross(m, rng.normal(size=3))
        t /= np.linalg.norm(t)
        a, l = rng.uniform(0.005, 0.1), rng.uniform(0.02, 0.48)
        d = -a * m + l * t
        E, g, H = energy(d, m)
        assert E > 0.0
        gfd, Hfd = np.empty(3), np.empty((3, 3))
        for j in range(3):
            e = np.zeros(3)
            e[j] = h
            (Ep, gp, _), (Em, gm, _) = energy(d + e, m), energy(d - e, m)
            gfd[j] = (Ep - Em) / (2 * h)
            Hfd[:, j] = (gp - gm) / (2 * h)
        np.testing.assert_allclose(g, gfd, rtol=1e-6, atol=1e-9 * np.abs(g).max())
        np.testing.assert_allclose(H, Hfd, rtol=1e-5, atol=1e-6 * np.abs(H).max())
        checked += 1
    assert checked == 40
    # beyond the fade length, and in front of the plane, nothing
    assert energy(-0.05 * m + 0.51 * t, m)[0] == 0.0
    assert energy(0.05 * m + 0.2 * t, m)[0] == 0.0


def _fan(rng):
    """A free vertex's fan (solver.core.kernels.contact.vertex_pair): two free edges with their
    triangles' normals and two inner edges, around v = 0; returns (ehat, nrm, free)."""
    while True:
        ehat = rng.normal(size=(4, 3))
        ehat[:, 2] = 0.3 * ehat[:, 2]                      # a gently curved fan
        ehat /= np.linalg.norm(ehat, axis=1)[:, None]
        nrm = np.cross(ehat, ehat[[1, 2, 3, 0]])          # edge q's triangle: (q, q + 1)
        nrm *= np.sign(nrm[:, 2])[:, None] / np.linalg.norm(nrm, axis=1)[:, None]
        # some direction must lie in the region (every alpha_k > 0)
        d = -ehat.sum(axis=0)
        if (d @ ehat.T < -0.1).all():
            return ehat, nrm, np.array([True, True, False, False])


def _vertex_law(d, ehat, nrm, free, vn, k, smooth, fade):
    from solver.core.kernels.contact import vertex_pair
    fe, ke = np.zeros(12), np.zeros((12, 12))
    e, depth = vertex_pair(np.asarray(d, float), 0, ehat, nrm, free, len(free),
                           np.asarray(vn, float), k, smooth, fade, True, fe, ke)
    return e, fe[:3], ke[:3, :3]


@pytest.mark.parametrize("smoothing", [0.0, 0.02])
def test_lip_law_is_c1_across_the_region_of_a_free_vertex(rng, smoothing):
    """In the region of a vertex on the rim of a slave's candidates the lip law blends
    the plain penalty psi(|d|) (where the region meets an inner edge's) into the faded
    one psi(a) phi(l / L) on a free edge's plane (where it meets that edge's): energy and
    force match both neighbours on the boundary planes (so Newton meets no jump there),
    and inside the region the force is the energy's gradient and the tangent its
    Hessian."""
    k, fade, h = 2.0, 1.0, 1e-6
    checked = 0
    for _ in range(30):
        ehat, nrm, free = _fan(rng)
        inside = -ehat.sum(axis=0)
        for q in range(4):                 # onto the plane where the region meets edge q
            d = inside - (inside @ ehat[q]) * ehat[q]
            if not (d @ np.delete(ehat, q, axis=0).T < -1e-3).all():
                continue                   # that plane does not bound the region here
            d *= rng.uniform(0.02, 0.3) / np.linalg.norm(d)
            if free[q]:                    # behind the free edge's plane
                a = -(nrm[q] @ d)
                if a <= smoothing:
                    d = d - (a + 0.05) * nrm[q]
                    if not (d @ np.delete(ehat, q, axis=0).T < 0).all():
                        continue
            vn = -d / np.linalg.norm(d)    # the point behind the vertex, along its normal
            gaps = []                      # approaching the plane from inside the region
            for eps in (1e-8, 1e-10, 1e-12):
                x = d + eps * (d / np.linalg.norm(d) - ehat[q])
                if free[q]:                # the free edge's law, with its face normal
                    g_ref, H = np.empty(3), np.empty((3, 3))
                    e_ref = boundary_penalty(x, nrm[q], k, smoothing, fade, True, g_ref, H)[0]
                else:                      # the plain law on the inner edge's end
                    dist = np.linalg.norm(x)
                    e_ref, dpsi, _ = penalty_law(dist, k, smoothing)
                    g_ref = dpsi * x / dist
                e, g, H = _vertex_law(x, ehat, nrm, free, vn, k, smoothing, fade)
                assert e == pytest.approx(e_ref, rel=1e-5, abs=1e-12)
                gaps.append(np.abs(g - g_ref).max() / max(np.abs(g_ref).max(), 1e-6))
            # no jump in the force: the difference vanishes with eps (a jump would stay)
            assert min(gaps) < 1e-5 or gaps[2] < 0.02 * gaps[1] < 0.02 * gaps[0]
            checked += 1
        # inside the region: the force is the energy's gradient, the tangent its Hessian
        d = inside * rng.uniform(0.02, 0.3) / np.linalg.norm(inside)
        vn = -inside / np.linalg.norm(inside) + 0.3 * rng.normal(size=3)
        vn /= np.linalg.norm(vn)
        e, g, H = _vertex_law(d, ehat, nrm, free, vn, k, smoothing, fade)
        gfd, Hfd = np.empty(3), np.empty((3, 3))
        for j in range(3):
            dp, dm = d.copy(), d.copy()
            dp[j] += h
            dm[j] -= h
            (ep, gp, _), (em, gm, _) = (_vertex_law(dp, ehat, nrm, free, vn, k, smoothing, fade),
                                        _vertex_law(dm, ehat, nrm, free, vn, k, smoothing, fade))
            gfd[j], Hfd[:, j] = (ep - em) / (2 * h), (gp - gm) / (2 * h)
        np.testing.assert_allclose(g, gfd, rtol=1e-5, atol=1e-8)
        np.testing.assert_allclose(H, Hfd, rtol=1e-4, atol=1e-5 * np.abs(H).max())
    assert checked >= 30


def test_smoothed_law_is_c2_and_matches_the_pure_one_beyond_the_smoothing():
    k, s = 3.0, 0.1
    for p in (-s, s):                                   # C2 joins
        lo, hi = penalty_law(p - 1e-9, k, s), penalty_law(p + 1e-9, k, s)
        np.testing.assert_allclose(lo, hi, atol=1e-7)
    psi, f, kk = penalty_law(0.4, k, s)
    assert f == pytest.approx(k * 0.4) and kk == k      # force k p beyond s, as the pure law
    assert penalty_law(-s, k, s) == (0.0, 0.0, 0.0)
    assert penalty_law(-1e-3, k, 0.0) == (0.0, 0.0, 0.0)


# ----------------------------------------------------------------- rigid surface

def test_block_on_rigid_plane_carries_the_load():
    L, F = 8.0, 1.0
    mesh = box(4, 4, 2, (L, L, 4.0), origin=(-L / 2, -L / 2, 0.0))
    plane = grid_surface(5, 20.0)                       # its edges do not meet the block's
    term = RigidContact(mesh, mesh.node_sets["zmin"], plane)
    model = solver.Model(mesh)
    model.fix(mesh.node_sets["xmin"], components=(0,))  # rollers: no normal (z) reaction
    model.fix(mesh.node_sets["ymin"], components=(1,))
    faces = mesh.boundary_faces()
    top_faces = faces[np.isin(faces, mesh.node_sets["zmax"]).all(axis=1)]
    load = F / L**2 * tributary_areas(mesh.nodes, top_faces, mesh.n_nodes)   # uniform
    model.add_force(np.arange(mesh.n_nodes), np.outer(load, [0.0, 0.0, -1.0]))
    model.add_term(term)
    res = model.solve_static()
    assert res.converged
    assert term.n_active == len(term.slaves)
    np.testing.assert_allclose(term.nodal_force.sum(axis=0), [0.0, 0.0, F], atol=0.01 * F)
    assert term.total_force == pytest.approx(F, rel=0.01)
    assert term.max_penetration < 0.05
    np.testing.assert_array_equal(np.flatnonzero(term.touching()),
                                  np.sort(mesh.node_sets["zmin"]))
    # uniform pressure F / L^2 on k = penalty * area: a uniform penetration
    np.testing.assert_allclose(-term.gap, F / L**2 / PENALTY, rtol=1e-3)


def test_sheet_is_oriented_towards_the_tissue_and_nodes_behind_it_are_dropped():
    mesh = box(2, 2, 2, (4.0, 4.0, 2.0), origin=(-2.0, -2.0, 0.5))
    flipped = grid_surface(4, 12.0)
    flipped.triangles = flipped.triangles[:, ::-1]            # normals down, away from it
    term = RigidContact(mesh, mesh.node_sets["zmin"], flipped)
    assert term.flipped and term.initial_gap.min() == pytest.approx(0.5)
    # a sheet at z = 1.2, between the bottom (z = 0.5) and the top (z = 2.5) nodes: most
    # slaves are above it, the bottom ones behind it are dropped
    sheet = grid_surface(4, 12.0, lambda x, y: 0.0 * x + 1.2)
    bottom, top = mesh.node_sets["zmin"][:4], mesh.node_sets["zmax"]
    term = RigidContact(mesh, np.concatenate([bottom, top]), sheet, area=1.0)
    assert not term.flipped
    assert set(term.dropped) == set(bottom) and set(term.slaves) == set(top)
    np.testing.assert_allclose(term.initial_gap, 1.3)


def test_no_contact_beyond_the_free_edge_of_a_sheet_without_fade():
    sheet = grid_surface(2, 4.0)                              # [-2, 2]^2 at z = 0
    mesh = box(1, 1, 1, (1.0, 1.0, 1.0), origin=(-0.5, -0.5, 0.2))
    term = RigidContact(mesh, mesh.node_sets["zmin"], sheet, area=1.0, fade=0.0)
    u = np.zeros((mesh.n_nodes, 3))
    u[:, 2] = -0.3                                            # 0.1 mm into the sheet
    run = Runner(term, mesh.n_nodes)
    run(u)
    assert term.n_active == 4 and term.max_penetration == pytest.approx(0.1)
    u[:, 0] = 2.0                                             # half the nodes off the edge
    run(u)
    assert term.n_active == 2 and np.isinf(term.gap).sum() == 2


def _rest_and_pushed(term, mesh, push):
    """The force on each slave (s, 3) at rest and with every node moved by push (3,)."""
    run = Runner(term, mesh.n_nodes)
    out = []
    for u in (np.zeros((mesh.n_nodes, 3)), np.tile(push, (mesh.n_nodes, 1))):
        out.append(-run(u, need_k=False).residual.reshape(-1, 3)[term.slaves])
    return out


@pytest.mark.parametrize("smoothing", [0.0, 0.02])
def test_slaves_pushed_on_at_rest_are_offset_onto_the_surface(smoothing):
    """Bottom nodes 0.05 mm behind a plane at rest (within rest_tolerance): with the rest
    offset the rest state carries no force (a smoothed law's slaves rest at the gap s where
    it begins) and a further push of 0.02 mm meets the law 0.02 mm on; without it the rest
    state is pushed on by the 0.05 mm penetration."""
    mesh = box(2, 2, 1, (2.0, 2.0, 1.0), origin=(-1.0, -1.0, -0.05))
    plane = grid_surface(4, 12.0)
    bottom = mesh.node_sets["zmin"]
    push = np.array([0.0, 0.0, -0.02])
    term = RigidContact(mesh, bottom, plane, area=1.0, smoothing=smoothing)
    np.testing.assert_allclose(term.offset, np.tile([0.0, 0.0, 0.05 + smoothing],
                                                    (len(bottom), 1)), atol=1e-12)
    rest, pushed = _rest_and_pushed(term, mesh, push)
    assert np.abs(rest).max() < 1e-12
    law = penalty_law(0.02 - smoothing, PENALTY, smoothing)[1]    # the rest is at p = -s
    np.testing.assert_allclose(pushed, np.tile([0.0, 0.0, law], (len(bottom), 1)), rtol=1e-9,
                               atol=1e-12)
    old = RigidContact(mesh, bottom, plane, area=1.0, smoothing=smoothing, rest_offset=False)
    assert not old.offset.any()
    rest, pushed = _rest_and_pushed(old, mesh, push)
    np.testing.assert_allclose(rest[:, 2], penalty_law(0.05, PENALTY, smoothing)[1])
    np.testing.assert_allclose(pushed[:, 2], penalty_law(0.07, PENALTY, smoothing)[1])


def test_slave_behind_a_rim_at_rest_is_offset_onto_the_rims_plane():
    """A node beyond the free edge x = 2 of a sheet (fade 1 mm) and 0.2 mm behind its plane
    at rest (no side there, so rest_tolerance does not drop it; the faded penalty pushed on
    such nodes of the reference face's upper teeth with 6 N each): its offset is along the
    rim's normal onto the plane, and a further push meets the faded penalty again."""
    sheet = grid_surface(2, 4.0)                               # [-2, 2]^2 at z = 0
    mesh = box(1, 1, 1, (0.8, 0.2, 1.0), origin=(1.5, -0.1, -0.2))
    term = RigidContact(mesh, mesh.node_sets["zmin"], sheet, area=1.0)
    node = term.slaves                   # those at x = 2.3; those over the sheet are dropped
    np.testing.assert_allclose(mesh.nodes[node, 0], 2.3)
    np.testing.assert_allclose(term.offset, np.tile([0.0, 0.0, 0.2], (len(node), 1)),
                               atol=1e-12)
    rest, pushed = _rest_and_pushed(term, mesh, np.array([0.0, 0.0, -0.05]))
    assert np.abs(rest).max() < 1e-12
    assert (pushed[:, 2] > 0.0).all()
    old = RigidContact(mesh, mesh.node_sets["zmin"], sheet, area=1.0, rest_offset=False)
    assert (_rest_and_pushed(old, mesh, np.zeros(3))[0][:, 2] > 0.0).all()


def test_penalty_fades_continuously_around_the_rim_of_a_sheet():
    """A node behind a warped sheet (z = 0.4 x y: the two triangles at the corner (2, 2)
    that hold its free edges have normals 0.35 rad apart) walks out over the free edge
    x = 2, around the corner and back over the edge y = 2: its force has no jump, also where
    the edge's region meets the corner's (the lips' fade, with the face normal of the
    nearest triangle, jumps there), leaves the edge along that triangle's normal, fades out
    over the fade length, and the term's tangent is the derivative of its force beyond an
    edge (where the fade's normal is fixed)."""
    sheet = grid_surface(4, 4.0, height=lambda x, y: 0.4 * x * y)
    mesh = box(1, 1, 1, (0.2, 0.2, 0.2), origin=(1.0, 1.0, 2.0))
    node = mesh.node_sets["zmin"][:1]
    term = RigidContact(mesh, node, sheet, area=1.0, search_radius=3.0)
    assert term.fade == 1.0
    run = Runner(term, mesh.n_nodes)
    x0 = mesh.nodes[node[0]]

    def force(p):
        u = np.zeros((mesh.n_nodes, 3))
        u[node[0]] = p - x0
        return -run(u, need_k=False).residual.reshape(-1, 3)[node[0]]

    def at(x, y):           # 0.15 mm behind both corner triangles' planes (through (2, 2))
        z = 1.6 + min(0.4 * (x - 2) + 0.8 * (y - 2), 0.8 * (x - 2) + 0.4 * (y - 2))
        return np.array([x, y, z - 0.15])

    t = np.linspace(0.0, 1.0, 1500)
    legs = [np.column_stack([1.7 + 0.6 * t, 1.7 + 0 * t]),             # over x = 2
            np.column_stack([2.3 + 0 * t, 1.7 + 0.6 * t]),             # past the corner
            np.column_stack([2.3 - 0.6 * t, 2.3 + 0 * t])]             # over y = 2
    F = np.array([force(at(x, y)) for x, y in np.vstack(legs)])
    size = np.linalg.norm(F, axis=1)
    assert (size > 0.05).all()
    assert np.linalg.norm(np.diff(F, axis=0), axis=1).max() < 0.005 * size.max()
    n1 = np.cross([1.0, 0.0, 0.4], [0.0, 1.0, 0.8])                    # triangle at x = 2
    f = force(at(2.0 + 1e-6, 1.7))
    np.testing.assert_allclose(f / np.linalg.norm(f), n1 / np.linalg.norm(n1), atol=1e-5)
    assert np.allclose(force(at(3.1, 1.7)), 0.0)                       # beyond the fade
    p = at(2.4, 1.7)
    u = np.zeros((mesh.n_nodes, 3))
    u[node[0]] = p - x0
    i = 3 * node[0]
    K = run(u).matrix().toarray()[i:i + 3, i:i + 3]
    h, Kfd = 1e-6, np.zeros((3, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        Kfd[:, j] = -(force(p + e) - force(p - e)) / (2 * h)
    np.testing.assert_allclose(K, Kfd, rtol=1e-5, atol=1e-6 * np.abs(K).max())


def test_block_slides_on_a_frictionless_incline():
    theta = np.radians(25.0)
    c, s = np.cos(theta), np.sin(theta)
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])  # about x: z -> normal n
    n, t = R[:, 2], R[:, 1]
    plane = grid_surface(6, 30.0, rotation=R)
    mesh = box(3, 3, 2, (6.0, 6.0, 3.0), origin=(-3.0, -3.0, 0.0),
               mapping=lambda p: p @ R.T)
    term = RigidContact(mesh, mesh.node_sets["zmin"], plane)
    model = solver.Model(mesh)
    model.add_term(term)
    top = mesh.node_sets["zmax"]
    slide, press = 2.0, 0.3
    model.prescribe(top, displacement=slide * t - press * n)
    res = model.solve_static(steps=2)
    assert res.converged
    reaction = res.reaction(top)                              # force on the block at its top
    assert reaction @ n < -0.02                               # pressed into the plane
    assert abs(reaction @ t) < 1e-4 * abs(reaction @ n)       # no tangential resistance
    assert abs(reaction[0]) < 1e-4 * abs(reaction @ n)
    np.testing.assert_allclose(term.nodal_force.sum(axis=0), -reaction, atol=1e-6)
    bottom = res.displacement[mesh.node_sets["zmin"]] @ t
    assert bottom.mean() == pytest.approx(slide, rel=0.02)     # it slid along
    assert term.max_penetration < 0.05


# --------------------------------------------------------------------- lip on lip

def test_two_blocks_pressed_together_by_forces():
    F = 1.0                                                  # N, on 25 mm^2
    mesh, ida, idb, fa, fb = two_blocks()
    term = LipContact(mesh, fb, fa)                          # closed surfaces of both blocks
    Runner(term, mesh.n_nodes)(np.zeros((mesh.n_nodes, 3)))
    assert len(term.dropped) == 0 and term.max_penetration < 1e-12
    assert np.abs(mesh.nodes[term.slaves[term.gap <= 0], 2]).max() == 0.0  # touching faces
    model = solver.Model(mesh, STIFF)
    model.fix(mesh.node_sets["A_zmin"])
    model.fix(mesh.node_sets["B_xmin"], components=(0,))
    model.fix(mesh.node_sets["B_ymin"], components=(1,))
    top = mesh.node_sets["B_zmax"]
    model.add_force(top, np.outer(np.full(len(top), F / len(top)), [0.0, 0.0, -1.0]))
    model.add_term(term)
    res = model.solve_static(steps=2)
    assert res.converged
    on_a, on_b = term.nodal_force[ida].sum(axis=0), term.nodal_force[idb].sum(axis=0)
    np.testing.assert_allclose(on_b, [0.0, 0.0, F], atol=0.01 * F)
    np.testing.assert_allclose(on_a, -on_b, atol=1e-9)        # equal and opposite
    assert term.max_penetration < 0.05
    act = term.slaves[term.gap <= 0]                          # only the facing faces touch
    assert len(act) >= 10 and np.abs(mesh.nodes[act, 2]).max() == 0.0
    assert res.reaction(mesh.node_sets["A_zmin"])[2] == pytest.approx(F, rel=0.01)  # support


def test_half_model_keeps_contact_on_the_symmetry_plane():
    # the halves x <= 0 of two touching blocks; their contact faces end on x = 0
    a = box(2, 2, 1, (4.0, 4.0, 2.0), origin=(-4.0, -2.0, -2.0))
    b = box(2, 2, 1, (3.0, 3.0, 2.0), origin=(-3.0, -1.5, 0.0))
    mesh = solver.Mesh(np.vstack([a.nodes, b.nodes]), np.vstack([a.bricks, b.bricks + a.n_nodes]))
    faces = mesh.boundary_faces()
    x = mesh.nodes
    top_a = faces[(np.isin(faces, np.arange(a.n_nodes)) & (x[faces, 2] == 0)).all(axis=1)]
    bottom_b = faces[(np.isin(faces, np.arange(a.n_nodes, mesh.n_nodes))
                      & (x[faces, 2] == 0)).all(axis=1)]
    plane = np.flatnonzero(x[:, 0] == 0.0)
    u = np.zeros((mesh.n_nodes, 3))
    u[a.n_nodes:] = [0.01, 0.0, -0.1]                         # B pressed in, x = 0 nodes out
    on_plane_b = np.intersect1d(plane, b.node_sets["zmin"] + a.n_nodes)
    cut = LipContact(mesh, bottom_b, top_a, fade=0.005)
    Runner(cut, mesh.n_nodes)(u)
    assert not np.isin(on_plane_b, cut.slaves[cut.gap <= 0]).any()  # beyond the free edge
    faded = LipContact(mesh, bottom_b, top_a, fade=0.02)          # by half the fade length
    Runner(faded, mesh.n_nodes)(u)
    on = np.isin(faded.slaves, on_plane_b)
    assert on.sum() == 3 and np.allclose(faded.gap[on], -0.1 * 0.5, rtol=1e-6)
    half = LipContact(mesh, bottom_b, top_a, mirror_nodes=plane)
    Runner(half, mesh.n_nodes)(u)
    assert np.isin(on_plane_b, half.slaves[half.gap <= 0]).all()     # mirrored: in contact
    assert half.max_penetration == pytest.approx(0.1, abs=1e-3)


def test_lip_contact_fades_beyond_the_edge_of_a_slaves_candidates():
    # one candidate triangle per slave: every edge of it borders no other candidate, so a
    # slave sliding off it at a fixed depth must not see its force jump (it did: the sign
    # test used the pseudo-normal of an edge whose other face was no candidate)
    mesh, ida, idb, fa, fb = two_blocks()
    term = LipContact(mesh, fb, fa, max_pairs=1, fade=0.5, divisions=1, follow=False)
    q = term.passes[0]                       # B's bottom nodes on A's top
    assert np.all(np.diff(q["ptr"]) == 1) and q["pair_free"].all()
    run = Runner(term, mesh.n_nodes)
    forces = []
    for dx in np.linspace(0.0, 3.0, 301):
        u = np.zeros((mesh.n_nodes, 3))
        u[idb] = [dx, 0.0, -0.05]
        run(u, False)
        forces.append(term.force[:len(q["slaves"])].copy())
    forces = np.array(forces)
    k = q["k"]
    assert forces[0] == pytest.approx(0.05 * k)                  # on its triangle
    assert np.abs(np.diff(forces, axis=0)).max() < 0.05 * (0.05 * k).max()
    assert (forces[-1] == 0).any()                               # slid off: released


@pytest.mark.parametrize("smoothing", [0.0, 0.02])
def test_faded_lip_penalty_has_consistent_derivatives_over_the_masters(rng, smoothing):
    """Slaves slid beyond the edges of their one candidate triangle each (warped masters),
    in the fade: the force on each slave is the energy's gradient, the master nodes take
    the reaction (the forces balance), and the tangent is the symmetric part of the
    residual's derivative (the face normal is held fixed in the force, so that the force
    stays continuous where the region meets a free vertex's; its turn is in the
    derivative)."""
    mesh, ida, idb, fa, fb = two_blocks(rng=rng, jitter=0.15)
    term = LipContact(mesh, fb, fa, max_pairs=1, fade=1.0, smoothing=smoothing,
                      divisions=1, follow=False)
    u = rng.normal(0.0, 0.01, (mesh.n_nodes, 3))
    u[idb] += [0.8, 0.5, -0.2]
    run = Runner(term, mesh.n_nodes)
    asm = run(u)
    K, r = asm.matrix().toarray(), asm.residual.copy()
    q = term.passes[0]
    x = term.positions(u)
    act = q["active"][q["active"] >= 0]
    w = np.empty(3)
    regions = [nearest(x[q["nodes"][p, 0]], x, term.normals[1].tris, q["pair_tri"][p:p + 1],
                       w, np.empty(3))[1] for p in act]
    assert sum(r != FACE for r in regions) >= 3 and FACE in regions
    masters = np.concatenate([p["nodes"][p["active"][p["active"] >= 0], 1:].ravel()
                              for p in term.passes])
    only = np.setdiff1d(np.concatenate([p["nodes"][p["active"][p["active"] >= 0], 0]
                                        for p in term.passes]), masters)
    assert len(only) >= 5                    # slaves that are no active pair's master
    slave_dofs = (3 * only[:, None] + np.arange(3)).ravel()
    Kfd, gfd = fd_derivatives(run, u, K, r)
    on = np.isin(np.arange(len(r)), slave_dofs) & (np.abs(r) > 0)
    np.testing.assert_allclose(r[on], gfd[on], rtol=1e-5, atol=1e-6 * np.abs(r).max())
    Ksym = 0.5 * (Kfd + Kfd.T)
    ss = np.ix_(slave_dofs, slave_dofs)
    assert np.abs(K[ss] - Ksym[ss]).max() < 1e-5 * np.abs(K).max()
    # over the masters, a free vertex's law holds its fan's edges and normals fixed
    assert np.abs(K - Ksym).max() < 0.02 * np.abs(K).max()
    np.testing.assert_allclose(term.nodal_force.sum(axis=0), 0.0, atol=1e-12)


@pytest.mark.parametrize("level", ["coarse", "paper"])
def test_generic_face_rests_without_contact_force(level):
    """The generated face's lips and cheeks clear the teeth and each other at rest: no
    offsets, no contact force."""
    from solver.face.anatomy.generic import generic_face
    anatomy = generic_face(level=level, half=True)
    n = anatomy.mesh.n_nodes
    for term in build_contact_terms(anatomy):
        assert np.abs(Runner(term, n)(np.zeros((n, 3)), need_k=False).residual).max() == 0.0
        assert not getattr(term, "offset", np.zeros(1)).any()


# -------------------------------------------------------------- reference face

@pytest.fixture(scope="module")
def face_anatomy(reference_face):
    from solver.face.anatomy.ansys import load_ansys_face
    return load_ansys_face(str(reference_face))


def _teeth_terms(anatomy, distance=3.0):
    lips = np.unique(np.concatenate([f.ravel() for f in anatomy.contact_surfaces.values()]))
    return [RigidContact(anatomy.mesh, nodes_near(anatomy.mesh, lips, surface, distance),
                         surface, name=name)
            for name, surface in anatomy.rigid_surfaces.items()]


@pytest.mark.slow                   # 55 s on a slow day: out of the default suite
def test_face_lips_on_teeth_under_oop(face_anatomy):
    free = solver.FaceModel(face_anatomy)
    free.set_activations({"OOP": 0.5})
    assert free.solve_static().converged
    face = solver.FaceModel(face_anatomy)
    teeth = _teeth_terms(face_anatomy)
    for term in teeth:
        assert len(term.slaves) > 50
        assert term.initial_gap.min() > 0.1                  # no initial penetration
        face.model.add_term(term)
    face.model.system().assemble(np.zeros(3 * face_anatomy.mesh.n_nodes))
    assert all(t.n_active == 0 and t.max_penetration == 0.0 for t in teeth)
    for term in teeth:                                        # without teeth: lips go in
        Runner(term, face_anatomy.mesh.n_nodes)(free.u)
    assert max(t.max_penetration for t in teeth) > 0.2
    face.set_activations({"OOP": 0.5})
    res = face.solve_static()
    assert res.converged
    for term in teeth:
        assert term.n_active > 0 and term.max_penetration < 0.05
    with_teeth, without = face.lip_outputs(), free.lip_outputs()
    print(f"\nOOP 0.5 lip protrusion (mm): without teeth {without['lip_protrusion']:.3f} "
          f"(upper {without['upper_lip_protrusion']:.3f}, lower "
          f"{without['lower_lip_protrusion']:.3f}); with teeth "
          f"{with_teeth['lip_protrusion']:.3f} (upper {with_teeth['upper_lip_protrusion']:.3f},"
          f" lower {with_teeth['lower_lip_protrusion']:.3f}); iterations {res.iterations}; "
          + "; ".join(f"{t.name}: {t.n_active} nodes, {t.total_force:.3f} N, "
                      f"{t.max_penetration:.4f} mm" for t in teeth))
    assert with_teeth["lip_protrusion"] > without["lip_protrusion"] + 0.2


@pytest.mark.slow       # 50 s; the fade it relies on: test_penalty_fades_continuously_...
def test_face_oop_buc_passes_the_teeth_rim_in_one_load_step(face_anatomy):
    """The paper's static OOP + BUC on the full reference face in one load step: a lip node
    passes a free edge of a teeth sheet near lam = 0.48. Released there (fade 0) its force
    jumps and Newton stalls, the load increment cut below 1e-6; with the faded rim penalty
    the load path goes through."""
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    scene = parse_scene({"scene": {"analysis": "static"}, "muscles": {"driven": ["BUC", "OOP"]},
                         "effects": {"teeth_contact": True, "lip_contact": False,
                                     "stiffening_rule": "intersect"}})
    sim = Simulation(scene, loaded_anatomy=face_anatomy)
    sim.set_activations({"OOP": 1.0, "BUC": 1.0})
    stats = sim.step(1.0)
    assert stats.converged, stats.reason
    assert all(t.fade > 0 for t in sim.contact)
    assert sum(t.total_force for t in sim.contact) > 0.1
    assert max(t.max_penetration for t in sim.contact) < 0.1   # 0.065 mm, 4.7 N upper teeth
    print("\n" + "; ".join(f"{t.name}: {t.n_active} nodes, {t.total_force:.3f} N, "
                          f"{t.max_penetration:.4f} mm" for t in sim.contact))


def test_reference_face_rests_without_contact_force(face_anatomy):
    """The published mesh puts six cheek nodes behind the upper teeth (four by 0.03 and
    0.10 mm; two beyond a rim, 0.42 mm behind its plane, 6.1 N each): offset onto them,
    the rest state carries no contact force, so a run with every muscle at rest stays at
    rest (before, the face jolted: the lips moved 0.013 / 0.016 mm in 0.1 s and the first
    10 ms took 118 Newton iterations)."""
    n = face_anatomy.mesh.n_nodes
    for offset in (True, False):
        terms = build_contact_terms(face_anatomy, rest_offset=offset)
        force = [np.abs(Runner(t, n)(np.zeros((n, 3)), need_k=False).residual).max()
                 for t in terms]
        if offset:
            assert max(force) < 1e-9
            moved = np.concatenate([np.linalg.norm(t.offset, axis=1) for t in terms
                                    if isinstance(t, RigidContact)])
            # four within 0.1 mm (rest_tolerance), two beyond a rim 0.42 mm behind its plane
            assert (moved > 0).sum() == 6 and (moved < 0.1).sum() == len(moved) - 2
            assert moved.max() < 0.5
        else:
            assert max(force) > 1.0


@pytest.mark.slow                   # about 40 s: 0.2 s of the reference face's gesture
def test_reference_face_gesture_passes_where_a_lip_slave_met_its_patchs_edge(face_anatomy):
    """benchmarks/fast_path.py's case a (OOP + RIS with lip and teeth contact, full face)
    to t = 0.2 s. With 12 candidate triangles per lip slave, slave 6302 reached a vertex on
    the edge of its patch at t = 0.18 s, where three triangles gave three laws: 4 to 10
    cutbacks per run, and with the exact faded derivatives every cutback failed at
    t = 0.184 s. With 24 the run passes with at most one cutback (one, at t = 0.15 s,
    where a slave's nearest triangle turns across a concave edge). At `balanced`'s substep
    error tolerance (5e-2 mm) it passes with none, and still fails with 12 candidates."""
    from solver.app.gestures import gesture
    from solver.app.scene import parse_scene
    from solver.app.simulation import Simulation
    sim = Simulation(parse_scene(gesture(0.2)), anatomy=str(DATA), half=False)
    cutbacks = []
    sim.run(on_record=lambda s, row: cutbacks.append(s.last.cutbacks if s.t > 0 else 0))
    assert sim.t == pytest.approx(0.2)
    assert sum(cutbacks) <= 1


def test_lip_candidates_follow_the_converged_state_and_the_system_pattern_with_them():
    """Block B slid 2.5 mm over A, pressed 0.05 mm in: with candidates picked at rest
    (4 per slave within 2 mm) some slaves are past their candidates' rim and lose part of
    the penalty; once the candidates follow the state (commit), every slave over A's top
    is held by the full penalty of the plane law. The System's pattern follows the new
    pairs, and the rest pairs come back exactly with the rest state (restore)."""
    from solver.core.system import System
    mesh, ida, idb, fa, fb = two_blocks()
    term = LipContact(mesh, fb, fa, max_pairs=4, radius=2.0, divisions=1, pattern_margin=0)
    q = term.passes[0]
    rest = (q["ptr"].copy(), q["pair_tri"].copy())
    sysm = System([term], mesh.n_nodes, [])
    u = np.zeros((mesh.n_nodes, 3))
    u[idb] = [2.5, 0.0, -0.05]
    x = mesh.nodes + u
    over = (np.abs(x[q["slaves"], 0]) < 3.9) & (np.abs(x[q["slaves"], 1]) < 3.9) \
        & (np.abs(x[q["slaves"], 2] + 0.05) < 1e-9)                     # B's pressed bottom
    run = Runner(term, mesh.n_nodes)
    run(u, False)
    full = 0.05 * q["k"]
    before = term.force[:len(q["slaves"])].copy()
    assert (before[over] < 0.99 * full[over]).any()                # past the rim: faded
    generation = term.blocks_generation
    sysm.commit(u.ravel())
    assert term.blocks_generation == generation + 1
    q = term.passes[0]
    from solver.core.assembly import block_dofs
    assert all(np.array_equal(d, block_dofs(b)) for d, b in zip(sysm.pattern.dofs,
                                                                term.blocks()))
    run = Runner(term, mesh.n_nodes)
    run(u, False)
    after = term.force[:len(q["slaves"])]
    assert after[over] == pytest.approx(full[over], rel=1e-9)
    sysm.restore(np.zeros(3 * mesh.n_nodes))
    q = term.passes[0]
    assert np.array_equal(q["ptr"], rest[0]) and np.array_equal(q["pair_tri"], rest[1])
    assert term.blocks_generation == generation + 2


def test_the_pattern_block_holds_the_followed_candidates_and_is_part_of_the_state():
    """The slide of the test above with the default pattern margin: the new candidates
    fall in the pattern block made at rest (no new pattern), each pair scatters into the
    row of its own nodes, and the forces are those of a term whose pattern follows every
    change (pattern_margin 0). A snapshot taken there brings that pattern back after a
    restore elsewhere; a snapshot that is not this system's is refused by name."""
    from solver.core.system import System
    mesh, ida, idb, fa, fb = two_blocks()
    u = np.zeros((mesh.n_nodes, 3))
    u[idb] = [2.5, 0.0, -0.05]
    forces, generations, systems = [], [], []
    for margin in (0.0, 3.0):
        term = LipContact(mesh, fb, fa, max_pairs=4, radius=2.0, divisions=1,
                          pattern_margin=margin)
        sysm = System([term], mesh.n_nodes, [])
        generation = term.blocks_generation
        sysm.commit(u.ravel())
        generations.append(term.blocks_generation - generation)
        for q in term.passes:
            assert np.array_equal(q["block"][q["rows"]], q["nodes"])
        run = Runner(term, mesh.n_nodes)
        run(u, False)
        forces.append(term.force.copy())
        systems.append((sysm, term))
    assert generations == [1, 0]
    assert np.array_equal(forces[0], forces[1])
    sysm, term = systems[0]                                # the pattern made at u
    at_u = sysm.snapshot()
    sysm.restore(np.zeros(3 * mesh.n_nodes))                     # a pattern made at rest
    assert not np.array_equal(sysm.snapshot(), at_u)
    sysm.restore(u.ravel(), at_u)
    assert np.array_equal(sysm.snapshot(), at_u)
    with pytest.raises(ValueError, match="pattern"):
        sysm.restore(u.ravel(), at_u[:-1])
    with pytest.raises(ValueError, match=term.name):
        term.set_pattern_state(at_u[1:] + 10 ** 6)
    assert np.array_equal(sysm.snapshot(), at_u)                 # left as it was


def test_min_facing_is_the_smallest_normal_product_over_the_faces_at_each_node():
    """solver.core.kernels.contact.min_facing against a direct loop: for each pair, the
    smallest n_f . m over the slave surface's triangles f at the pair's node (inf for a
    node on no triangle), on a random triangle soup."""
    from solver.core.kernels.contact import min_facing
    from solver.core.terms.base import pack_parts, unpack_parts
    rng = np.random.default_rng(3)
    n = 12
    tris = rng.integers(0, n - 2, size=(15, 3))               # nodes n-2, n-1 on none
    fn = rng.normal(size=(15, 3))
    fn /= np.linalg.norm(fn, axis=1)[:, None]
    order = np.argsort(tris.ravel(), kind="stable")
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(tris.ravel(), minlength=n), out=ptr[1:])
    nodes = rng.integers(0, n, size=40)
    master = rng.normal(size=(40, 3))
    out = np.empty(40)
    min_facing(ptr, order // 3, fn, nodes, master, out)
    for p, v in enumerate(nodes):
        faces = [f for f in range(15) if v in tris[f]]
        expected = min((fn[f] @ master[p] for f in faces), default=np.inf)
        assert out[p] == pytest.approx(expected, abs=1e-14), (p, v)
    assert np.isinf(out[nodes >= n - 2]).all() and np.isfinite(out[nodes < n - 2]).any()
    # the pattern state's packing round-trips and refuses what does not fit
    parts = [np.array([3, 1]), np.array([], dtype=np.int64), np.array([7])]
    back = unpack_parts(pack_parts(parts), 3, "test")
    assert all(np.array_equal(a, b) for a, b in zip(parts, back))
    with pytest.raises(ValueError, match="test"):
        unpack_parts(pack_parts(parts)[:-1], 3, "test")
