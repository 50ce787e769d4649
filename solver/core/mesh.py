"""Hexahedral meshes: nodes (n, 3) in mm, 8-node bricks (m, 8), named sets.

Wedges are bricks with repeated node ids (ANSYS degenerate SOLID185). A brick that is
inverted or of zero volume (det J <= 0 at a Gauss point) is rejected at construction,
with an error naming its id.
"""

from dataclasses import dataclass, field

import numpy as np

from solver.core.element import reference_geometry
from solver.core.errors import MeshError

# A brick's six faces as local node indices (k = 0 .. 7 in the element's order), each
# wound with its normal pointing out of the brick: bottom, top, then the four sides.
BRICK_FACES = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4],
                        [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])


@dataclass
class Mesh:
    """Nodes and bricks of a solid mesh.

    nodes        (n, 3) float64, mm
    bricks       (m, 8) int64, 0-based node ids in ANSYS order (I..P)
    node_sets    name -> sorted unique node ids (k,)
    element_sets name -> sorted unique brick ids (k,)
    node_ids, element_ids: the ids of a source file (n,), (m,), used in messages; by
    default 0..n-1 and 0..m-1.
    """

    nodes: np.ndarray
    bricks: np.ndarray
    node_sets: dict = field(default_factory=dict)
    element_sets: dict = field(default_factory=dict)
    node_ids: np.ndarray = None
    element_ids: np.ndarray = None

    def __post_init__(self):
        self.nodes = np.ascontiguousarray(self.nodes, dtype=np.float64)
        bricks = np.asarray(self.bricks)
        if self.nodes.ndim != 2 or self.nodes.shape[1] != 3:
            raise MeshError(f"nodes must have shape (n, 3), got {self.nodes.shape}")
        if not np.all(np.isfinite(self.nodes)):
            bad = int(np.argwhere(~np.isfinite(self.nodes))[0, 0])
            raise MeshError(f"node {self._nid(bad)} has a non-finite coordinate")
        if bricks.ndim != 2 or bricks.shape[1] != 8:
            raise MeshError(f"bricks must have shape (m, 8), got {bricks.shape}")
        if not np.issubdtype(bricks.dtype, np.integer):
            raise MeshError(f"bricks must hold integer node ids, got {bricks.dtype}")
        self.bricks = np.ascontiguousarray(bricks, dtype=np.int64)
        n = len(self.nodes)
        if self.node_ids is None:
            self.node_ids = np.arange(n)
        if self.element_ids is None:
            self.element_ids = np.arange(len(self.bricks))
        bad = np.argwhere((self.bricks < 0) | (self.bricks >= n))
        if len(bad):
            e = int(bad[0, 0])
            raise MeshError(f"brick {self.element_ids[e]} refers to node index "
                            f"{self.bricks[e, bad[0, 1]]}, outside 0..{n - 1}")
        self.node_sets = {k: np.unique(np.asarray(v, dtype=np.int64))
                          for k, v in self.node_sets.items()}
        self.element_sets = {k: np.unique(np.asarray(v, dtype=np.int64))
                             for k, v in self.element_sets.items()}
        self.det_j, self.dn_dx = reference_geometry(self.nodes, self.bricks)
        bad = np.flatnonzero(self.det_j.min(axis=1) <= 0.0)
        if len(bad):
            e = int(bad[0])
            kind = "inverted" if self.det_j[e].min() < 0 else "of zero volume"
            raise MeshError(f"brick {self.element_ids[e]} is {kind} (min det J = "
                            f"{self.det_j[e].min():.3g} at a Gauss point); "
                            f"{len(bad)} bad brick(s) in all")

    def _nid(self, i):
        return self.node_ids[i] if self.node_ids is not None else i

    @property
    def n_nodes(self):
        return len(self.nodes)

    @property
    def n_bricks(self):
        return len(self.bricks)

    @property
    def is_wedge(self):
        """(m,) bool: bricks with repeated node ids (degenerate)."""
        s = np.sort(self.bricks, axis=1)
        return (np.diff(s, axis=1) == 0).any(axis=1)

    @property
    def volumes(self):
        """(m,) reference volume of each brick, mm^3."""
        return self.det_j.sum(axis=1)

    @property
    def bounding_box(self):
        """(3,) extent along x, y, z, mm."""
        return self.nodes.max(axis=0) - self.nodes.min(axis=0)

    def boundary_faces(self):
        """Quadrilateral faces (k, 4) that belong to one brick only (wedge faces may repeat ids)."""
        faces = self.bricks[:, BRICK_FACES].reshape(-1, 4)
        key = np.sort(faces, axis=1)
        degenerate = np.array([len(set(f)) < 3 for f in key])
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        keep = (counts[inv.ravel()] == 1) & ~degenerate
        return faces[keep]

    def submesh(self, brick_mask):
        """Mesh of the selected bricks, nodes renumbered; returns (mesh, old node ids (k,))."""
        bricks = self.bricks[brick_mask]
        used = np.unique(bricks)
        new = -np.ones(self.n_nodes, dtype=np.int64)
        new[used] = np.arange(len(used))
        old_e = np.flatnonzero(brick_mask)
        enew = -np.ones(self.n_bricks, dtype=np.int64)
        enew[old_e] = np.arange(len(old_e))
        nsets = {k: new[v][new[v] >= 0] for k, v in self.node_sets.items()}
        esets = {k: enew[v][enew[v] >= 0] for k, v in self.element_sets.items()}
        return Mesh(self.nodes[used], new[bricks], nsets, esets,
                    self.node_ids[used], self.element_ids[old_e]), used
