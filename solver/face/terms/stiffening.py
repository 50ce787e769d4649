r"""Activation stiffening: bricks near an active fibre get stiffer (the paper's Figure 7).

For a brick e in the neighbourhood of muscles M_e, c10 and c20 become k_e c10, k_e c20
with k_e = max_{m in M_e} k(a_m) (solver.face.muscles). Written as an additive term: the extra
isochoric energy (k_e - 1) W_iso(c10, c20) on those bricks only (d = inf: no volumetric
part, which the elasticity term already holds), so that it adds to the residual and
tangent like every other term, and costs nothing while no driven muscle is active.

The neighbourhood of a muscle is the set of bricks that a sphere of radius r swept along
its fibres intersects, computed once per anatomy: a brick is taken where the fibre passes
through it, or where one of its 4 x 4 x 4 sample points (corners, edges, faces, inside)
lies within r of the fibre (sampled at r/4); the miss is at most a third of a brick edge.

Rules (MuscleProperties.stiffening_rule):
* "intersect" (the paper's): every brick of the neighbourhood takes the muscle's factor:
  k_e = k(a). The stiffened volume is that of the bricks, so it shrinks as the mesh is
  refined (RIS on the generic face: 5,458 mm^3 coarse, 1,455 mm^3 fine) and each mesh
  level is a different model: no convergence under refinement.
* "volume" (default): k_e = 1 + w_e (k(a) - 1), w_e the fraction of the brick's volume
  within r of the fibres (its 4 x 4 x 4 cell-centre samples in the natural coordinates;
  the samples of a regular brick carry equal volume). The stiffened volume is that of
  the tube about the fibre whatever the mesh, so refinement converges to one model.
"""

import numpy as np
from scipy.spatial import cKDTree

from solver.face.anatomy.base import MUSCLE_NAMES
from solver.core.element import shape_functions
from solver.core.embedding import locate
from solver.core.terms.elasticity import Elasticity

_XI = np.stack(np.meshgrid(*[np.linspace(-1, 1, 4)] * 3, indexing="ij"), -1).reshape(-1, 3)


def fibre_samples(points, spacing):
    """Points (k, 3) along a polyline, at most `spacing` apart."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / spacing)), 1)
        out.append(a + np.outer(np.arange(1, n + 1) / n, b - a))
    return np.vstack(out)


def neighbourhood(mesh, fibres, radius, tree=None):
    """Sorted brick indices within `radius` (mm) of the fibres' polylines."""
    if not fibres:
        return np.zeros(0, dtype=np.int64)
    samples = np.vstack([fibre_samples(f.points, radius / 4) for f in fibres])
    if tree is None:
        tree = _sample_tree(mesh)
    hits = tree.query_ball_point(samples, radius)
    owner = np.repeat(np.arange(mesh.n_bricks), len(_XI))
    near = {int(owner[i]) for h in hits for i in h}
    host, _, inside, _ = locate(mesh, samples)
    near.update(int(h) for h in host[inside])
    return np.array(sorted(near), dtype=np.int64)


def _sample_tree(mesh):
    pts = np.einsum("sa,maj->msj", shape_functions(_XI), mesh.nodes[mesh.bricks])
    return cKDTree(pts.reshape(-1, 3))


_XI_CELLS = np.stack(np.meshgrid(*[np.linspace(-0.75, 0.75, 4)] * 3, indexing="ij"),
                     -1).reshape(-1, 3)


def _segment_distance(p, a, b):
    """(k,) distance of points p (k, 3) to the segment a-b."""
    ab = b - a
    t = np.clip((p - a) @ ab / max(ab @ ab, 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - a - t[:, None] * ab, axis=1)


def volume_fractions(mesh, bricks, fibres, radius):
    """(k,) fraction of each brick's volume within radius (mm) of the fibres' polylines."""
    if len(bricks) == 0 or not fibres:
        return np.zeros(len(bricks))
    pts = np.einsum("sa,maj->msj", shape_functions(_XI_CELLS), mesh.nodes[mesh.bricks[bricks]])
    flat = pts.reshape(-1, 3)
    d = np.full(len(flat), np.inf)
    for f in fibres:
        for a, b in zip(f.points[:-1], f.points[1:]):
            d = np.minimum(d, _segment_distance(flat, a, b))
    return (d <= radius).reshape(len(bricks), -1).mean(axis=1)


def muscle_weights(anatomy, regions, radii, rule):
    """muscle -> (k,) weights w_e of its region's bricks: 1 ('intersect') or the volume
    fraction within its radius ('volume')."""
    if rule == "intersect":
        return {m: np.ones(len(b)) for m, b in regions.items()}
    return {m: volume_fractions(anatomy.mesh, b, anatomy.muscle_fibres(m), radii[m])
            for m, b in regions.items()}


def muscle_neighbourhoods(anatomy, muscles, radii):
    """muscle -> brick indices (k,), for the given muscles."""
    tree = _sample_tree(anatomy.mesh)
    return {m: neighbourhood(anatomy.mesh, anatomy.muscle_fibres(m), radii[m], tree)
            for m in muscles}


class Stiffening(Elasticity):
    """Extra isochoric stiffness (k_e - 1) (c10, c20) on the bricks near driven muscles.

    host: the tissue's Elasticity term over every brick, or None. With a host the extra
    c10, c20 are added to the host's parameters of those bricks in the host's own kernel
    pass (W_iso is linear in c10 and c20, and the isochoric part is integrated at the
    Gauss points with the full F in both formulations, solver.core.kernels.brick): the same
    residual and tangent to rounding without a second pass over the bricks. This term then
    has no blocks and assembles nothing itself."""

    name = "stiffening"

    def __init__(self, mesh, base_params, regions, properties, activation, weights=None,
                 host=None):
        """base_params (m, 6) of the tissue; regions: muscle -> brick indices; weights:
        muscle -> (k,) weight of each region brick (default 1: the paper's rule); host:
        the tissue's Elasticity term (class docstring) or None."""
        subset = np.unique(np.concatenate([np.zeros(0, np.int64)] + list(regions.values())))
        super().__init__(mesh, np.zeros(6), "full", subset)
        self.properties, self.activation = properties, activation
        base = np.asarray(base_params, dtype=np.float64)[subset]
        self._c = base[:, [0, 2]]                               # c10, c20 of each brick
        self.params[:, 5] = np.inf                              # no volumetric part
        pos = {b: i for i, b in enumerate(subset)}
        self.weight = np.zeros((len(subset), len(MUSCLE_NAMES)))
        for m, bricks in regions.items():
            w = np.ones(len(bricks)) if weights is None else weights[m]
            self.weight[[pos[b] for b in bricks], MUSCLE_NAMES.index(m)] = w
        self.regions = regions
        self.host = host
        if host is not None:
            if len(host.subset) != mesh.n_bricks:
                raise ValueError("a stiffening host must cover every brick")
            where = np.empty(mesh.n_bricks, dtype=np.int64)
            where[host.subset] = np.arange(mesh.n_bricks)
            self._pos = where[subset]
            host.modifiers.append(self)

    def factors(self, lam):
        """(k,) stiffening factor of each brick of the subset at load factor lam."""
        k = self.properties.stiffening_factor(self.activation.at(lam))       # (10,)
        return (1.0 + self.weight * (k[None, :] - 1.0)).max(axis=1)

    def added_params(self, lam):
        """(positions in the host (k,), added parameters (k, 6)) at load factor lam, or
        None where no brick is stiffened."""
        f = self.factors(lam) - 1.0
        if not np.any(f > 0.0):
            return None
        added = np.zeros((len(f), 6))
        added[:, 0] = f * self._c[:, 0]
        added[:, 2] = f * self._c[:, 1]
        return self._pos, added

    def blocks(self):
        return [] if self.host is not None else super().blocks()

    def assemble(self, state, asm, block_ids):
        f = self.factors(state.lam) - 1.0
        if self.host is not None or not np.any(f > 0.0):
            return
        self.params[:, 0] = f * self._c[:, 0]
        self.params[:, 2] = f * self._c[:, 1]
        super().assemble(state, asm, block_ids)
