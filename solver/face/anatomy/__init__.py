"""Face anatomies: the procedural generic face and the published ANSYS reference face."""

from solver.face.anatomy.ansys import load_ansys_face
from solver.face.anatomy.base import (LANDMARK_NAMES, MUSCLE_FULL_NAMES, MUSCLE_NAMES,
                                      Anatomy, Fibre, RigidSurface)

__all__ = ["Anatomy", "Fibre", "RigidSurface", "MUSCLE_NAMES", "MUSCLE_FULL_NAMES",
           "LANDMARK_NAMES", "load_ansys_face"]
