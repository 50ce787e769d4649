r"""The mandible: a rigid body with prescribed motion, and what it carries.

Pose. Two inputs: the jaw opening theta (degrees), a rotation about the transverse axis
through the temporomandibular joints (the TMJ axis, along x) that lowers the chin, and
the jaw protrusion p (mm), a translation along the occlusal plane (+y, forward). A point
x of the mandible moves to

    x' = C + R(theta) (x - C) + p e_y,    R(theta) = rotation by -theta about e_x,

with C on the TMJ axis. The motion carries, rigidly: the tissue nodes attached to the
mandible (node set 'fixed_mandible'), the lower teeth (the vertices of the 'lower_teeth'
rigid surface that the upper teeth do not share) and the bony insertions of the muscles
that insert on the mandible (MANDIBLE_MUSCLES: DAO, DLI, MENT).

Within a step the pose runs linearly from its last committed value to its target, in
(theta, p), along the load path lam in [0, 1] (solver.core.model, solver.core.transient): the
prescribed nodes, the teeth and the insertions all follow the same rigid motion at
every substep.

Axis (jaw_geometry). Neither face includes the condyles, so C is placed from the incisor
point I: C = I + BONWILL_MM (-cos b e_y + sin b e_z), b = BALKWILL_DEG (the Bonwill
triangle, 86.6 mm, and the Balkwill angle), the occlusal plane being the mesh's horizontal
plane. I lies on the mid-line halfway between the lowest point of the upper teeth surface
and the highest point of the lower one, both within MIDLINE_MM of the mid-sagittal plane
and FRONT_MM of the surfaces' front.

Ranges (JAW_RANGES): opening 0 (teeth in occlusion) to 20 degrees, protrusion -1 to 10 mm.

Output. incisor_opening (mm) = |L' - I|, L the point of the mandible at I with the jaw
closed: 0 at rest, 2 * 86.6 sin(theta / 2) for a pure rotation.

Derivation of the axis and the sources of the ranges: docs/method.md, section 'The jaw's
axis and ranges'.
"""

import math
from dataclasses import dataclass

import numpy as np

from solver.core.errors import ParameterError

BONWILL_MM = math.sqrt(100.0 ** 2 - 50.0 ** 2)   # incisal point to intercondylar midpoint
BALKWILL_DEG = 22.5
MIDLINE_MM = 5.0
FRONT_MM = 10.0
MANDIBLE_MUSCLES = ("DAO", "DLI", "MENT")
JAW_INPUTS = ("jaw_opening", "jaw_protrusion")
JAW_UNITS = {"jaw_opening": "deg", "jaw_protrusion": "mm"}
JAW_RANGES = {"jaw_opening": (0.0, 20.0), "jaw_protrusion": (-1.0, 10.0)}


def check_jaw(name, value):
    """A float within JAW_RANGES[name], or a ParameterError naming the input and value."""
    if name not in JAW_RANGES:
        raise ParameterError(f"unknown jaw input {name!r}; known: {', '.join(JAW_INPUTS)}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r} is not a number") from None
    lo, hi = JAW_RANGES[name]
    if not math.isfinite(v) or v < lo or v > hi:
        raise ParameterError(f"{name} = {value!r} {JAW_UNITS[name]} is outside "
                             f"[{lo:g}, {hi:g}]")
    return v


@dataclass(frozen=True)
class JawGeometry:
    """centre (3,) mm: a point of the TMJ axis (the axis runs along x); incisor (3,) mm:
    the incisor point I; nodes (k,): the mesh nodes attached to the mandible."""

    centre: np.ndarray
    incisor: np.ndarray
    nodes: np.ndarray

    def transform(self, x, pose):
        """x (..., 3) mm moved by the pose (opening deg, protrusion mm)."""
        theta, p = math.radians(pose[0]), pose[1]
        c, s = math.cos(theta), math.sin(theta)
        r = np.asarray(x, dtype=np.float64) - self.centre
        out = np.empty_like(r)
        out[..., 0] = r[..., 0]
        out[..., 1] = c * r[..., 1] + s * r[..., 2]
        out[..., 2] = -s * r[..., 1] + c * r[..., 2]
        out += self.centre
        out[..., 1] += p
        return out

    def incisor_opening(self, pose):
        """mm: the distance the mandible's incisor point has moved from I."""
        return float(np.linalg.norm(self.transform(self.incisor, pose) - self.incisor))


def _front_point(vertices, highest):
    """(y, z) of the lowest (highest=False) or highest vertex among those within
    MIDLINE_MM of x = 0 and FRONT_MM of their front."""
    v = np.asarray(vertices, dtype=np.float64)
    v = v[np.abs(v[:, 0]) <= MIDLINE_MM]
    if not len(v):
        raise ParameterError(f"a teeth surface has no vertex within {MIDLINE_MM} mm of "
                             "the mid-sagittal plane")
    v = v[v[:, 1] >= v[:, 1].max() - FRONT_MM]
    return v[np.argmax(v[:, 2]) if highest else np.argmin(v[:, 2]), 1:]


def jaw_geometry(anatomy):
    """The JawGeometry of an Anatomy (module docstring): needs its 'upper_teeth' and
    'lower_teeth' rigid surfaces and its 'fixed_mandible' node set."""
    surfaces = anatomy.rigid_surfaces
    missing = [k for k in ("upper_teeth", "lower_teeth") if k not in surfaces]
    if missing or "fixed_mandible" not in anatomy.mesh.node_sets:
        raise ParameterError(f"anatomy {anatomy.name!r} has no jaw: it needs the rigid "
                             "surfaces 'upper_teeth', 'lower_teeth' and the node set "
                             "'fixed_mandible'")
    yz = 0.5 * (_front_point(surfaces["upper_teeth"].vertices, highest=False)
                + _front_point(surfaces["lower_teeth"].vertices, highest=True))
    incisor = np.array([0.0, yz[0], yz[1]])
    b = math.radians(BALKWILL_DEG)
    centre = incisor + BONWILL_MM * np.array([0.0, -math.cos(b), math.sin(b)])
    nodes = np.asarray(anatomy.mesh.node_sets["fixed_mandible"], dtype=np.int64)
    return JawGeometry(centre, incisor, nodes)


class Jaw:
    """The pose along a load path: start and target (opening deg, protrusion mm); at(lam)
    interpolates between them; geometry: JawGeometry."""

    def __init__(self, geometry):
        self.geometry = geometry
        self.start = np.zeros(2)
        self.target = np.zeros(2)

    def pose(self, opening=None, protrusion=None):
        """(2,) the target pose with opening and protrusion checked (check_jaw; None keeps
        the current target's): ParameterError naming a bad one, nothing changed."""
        new = self.target.copy()
        if opening is not None:
            new[0] = check_jaw("jaw_opening", opening)
        if protrusion is not None:
            new[1] = check_jaw("jaw_protrusion", protrusion)
        return new

    def at(self, lam):
        """(2,) the pose at load factor lam."""
        return self.start + lam * (self.target - self.start)

    @property
    def moving(self):
        """Whether the pose changes along the current path, or differs from rest."""
        return bool(np.any(self.start != self.target) or np.any(self.start != 0.0))

    def commit(self):
        self.start = self.target.copy()

    def displacement(self, pose):
        """(k, 3) mm: the displacements of the mandible's nodes at a pose, from rest."""
        x = self._rest_nodes
        if not np.any(np.asarray(pose) != 0.0):
            return np.zeros_like(x)                 # exactly: the closed jaw is the rest
        return self.geometry.transform(x, pose) - x

    def bind(self, rest_nodes):
        """Keep the rest positions (k, 3) of geometry.nodes (set by the face model)."""
        self._rest_nodes = np.asarray(rest_nodes, dtype=np.float64)
        return self

    def dof_values(self, lam):
        """(3 k,) the prescribed displacements of the mandible's DOFs at lam, in the
        order of dofs."""
        return self.displacement(self.at(lam)).ravel()

    @property
    def dofs(self):
        """(3 k,) DOF ids of the mandible's nodes, node-major."""
        n = self.geometry.nodes
        return (3 * n[:, None] + np.arange(3)).ravel()
