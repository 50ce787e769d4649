"""The anatomy object shared by the generic face and the ANSYS reference-face reader.

Axes: x medial-lateral (x = 0 mid-sagittal, subject's left at x < 0), y posterior-anterior
(larger y forward), z superior-inferior (larger z up). Units: mm.
"""

from dataclasses import dataclass, field

import numpy as np

from solver.core.mesh import Mesh

MUSCLE_NAMES = ("LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM")

MUSCLE_FULL_NAMES = {
    "LLSAN": "levator labii superioris alaeque nasi",
    "LAO": "levator anguli oris",
    "ZYG": "zygomaticus major",
    "RIS": "risorius",
    "BUC": "buccinator",
    "DAO": "depressor anguli oris",
    "DLI": "depressor labii inferioris",
    "MENT": "mentalis",
    "OOP": "orbicularis oris peripheralis",
    "OOM": "orbicularis oris marginalis",
}

# Node sets every anatomy provides (ids into mesh.nodes):
#   fixed          skull attachments: inner surface where tissue lies on bone
#   midsagittal    nodes on x = 0
# Landmarks (single node ids), see Anatomy.landmarks:
#   upper_lip_edge, lower_lip_edge    mid-sagittal points at the lip edges (the mouth slit)
#   upper_lip_front, lower_lip_front  mid-sagittal points at the front of the vermilion
#   corner_left, corner_right         mouth corners (x < 0 and x > 0)
LANDMARK_NAMES = ("upper_lip_edge", "lower_lip_edge", "upper_lip_front", "lower_lip_front",
                  "corner_left", "corner_right")


@dataclass
class Fibre:
    """One muscle fibre: a chain of cable elements between consecutive points.

    muscle     one of MUSCLE_NAMES
    side       'left' (x <= 0), 'right' (x >= 0), ends on x = 0 allowed; 'mid' for a chain
               with points on both sides
    points     (k, 3) mm, the cable nodes in order
    insertion  (k,) bool, True where the point is attached to bone (fixed)
    """

    muscle: str
    side: str
    points: np.ndarray
    insertion: np.ndarray

    @property
    def n_cables(self):
        return len(self.points) - 1


@dataclass
class RigidSurface:
    """A rigid triangulated surface (teeth and gums): vertices (p, 3) mm, triangles (t, 3)."""

    vertices: np.ndarray
    triangles: np.ndarray


@dataclass
class Anatomy:
    """A face: mesh with named sets, muscle fibres, landmarks and contact surfaces.

    mesh              Mesh with node_sets 'fixed', 'midsagittal' (and more) and
                      element_sets such as 'layer_outer', 'layer_middle', 'layer_inner'
    fibres            list of Fibre, both sides
    landmarks         name -> node id (see LANDMARK_NAMES)
    contact_surfaces  'upper_lip', 'lower_lip' -> (f, 3) or (f, 4) node-id faces of the mesh
    rigid_surfaces    'upper_teeth', 'lower_teeth' -> RigidSurface
    half              True when only x <= 0 is kept (u_x = 0 on 'midsagittal')
    """

    name: str
    mesh: Mesh
    fibres: list
    landmarks: dict
    contact_surfaces: dict = field(default_factory=dict)
    rigid_surfaces: dict = field(default_factory=dict)
    half: bool = False

    def muscle_fibres(self, muscle):
        """The fibres of one muscle, both sides."""
        return [f for f in self.fibres if f.muscle == muscle]

    def summary(self):
        """Counts per muscle: name -> (fibres, cable elements), summed over the sides."""
        out = {}
        for m in MUSCLE_NAMES:
            fs = self.muscle_fibres(m)
            out[m] = (len(fs), sum(f.n_cables for f in fs))
        return out
