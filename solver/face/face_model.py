"""A face model: an anatomy with its muscles, boundary conditions and lip outputs.

    face = FaceModel(anatomy)                    # all ten muscles, stiffening on
    face.set_activations({"OOP": 0.5})
    res = face.solve_static()
    face.lip_outputs()                           # aperture, protrusion, width (mm)

Boundary conditions: the anatomy's 'fixed' nodes (skull attachments) are held; on a half
face, u_x = 0 on the 'midsagittal' nodes. Those of them on the mandible ('fixed_mandible')
follow the jaw's prescribed rigid motion (solver.face.jaw; set_jaw), with the insertions of
the muscles on the mandible. Only the driven muscles' cables are built, and stiffening
only covers their neighbourhoods.
"""

import numpy as np

from solver.face import aperture
from solver.face.activation import Activation
from solver.face.anatomy.base import MUSCLE_NAMES
from solver.core.errors import ParameterError
from solver.face.jaw import Jaw, jaw_geometry
from solver.core.materials import MooneyRivlin
from solver.core.model import Model
from solver.face.muscles import MuscleProperties
from solver.face.terms.cables import Cables
from solver.core.strain import log_principal_strains
from solver.face.terms.stiffening import Stiffening, muscle_neighbourhoods, muscle_weights
from solver.core.transient import relax as relax_to_equilibrium

LIP_OUTPUTS = ("lip_aperture", "lip_protrusion", "lip_width", "upper_lip_protrusion",
               "lower_lip_protrusion")


class FaceModel:
    """anatomy; material (MooneyRivlin); muscles: the driven ones (default all ten);
    stiffening on or off; properties: MuscleProperties; formulation; linear_solver."""

    def __init__(self, anatomy, material=None, muscles=MUSCLE_NAMES, stiffening=True,
                 properties=None, formulation="mean_dilatation", linear_solver="auto"):
        unknown = [m for m in muscles if m not in MUSCLE_NAMES]
        if unknown:
            raise ParameterError(f"unknown muscle(s) {unknown}; known: {list(MUSCLE_NAMES)}")
        self.anatomy = anatomy
        self.muscles = tuple(m for m in MUSCLE_NAMES if m in muscles)
        self.material = material or MooneyRivlin()
        self.properties = properties or MuscleProperties()
        self.model = Model(anatomy.mesh, self.material, formulation, linear_solver)
        mesh = anatomy.mesh
        self.model.fix(mesh.node_sets["fixed"])
        if anatomy.half:
            self.model.fix(mesh.node_sets["midsagittal"], components=(0,))
        self.activation = Activation()
        self.jaw = None
        if "fixed_mandible" in mesh.node_sets and {"upper_teeth", "lower_teeth"} <= set(
                anatomy.rigid_surfaces):
            geometry = jaw_geometry(anatomy)
            self.jaw = Jaw(geometry).bind(mesh.nodes[geometry.nodes])
            self.model.add_motion(self.jaw)
        self.cables = None
        self.stiffening = None
        if self.muscles:
            self.cables = Cables(anatomy, self.muscles, self.properties, self.activation,
                                 self.jaw)
            self.model.add_term(self.cables)
            if stiffening:
                weights = muscle_weights(anatomy, self.regions,
                                         self.properties.stiffening_radius,
                                         self.properties.stiffening_rule)
                self.stiffening = Stiffening(mesh, self.model.elasticity.params,
                                             self.regions, self.properties, self.activation,
                                             weights, host=self.model.elasticity)
                self.model.add_term(self.stiffening)

    @property
    def lip_contours(self):
        """(upper, lower) mid-sagittal edges (k, 2) of the lip contact surfaces."""
        if not hasattr(self, "_contours"):
            mid = self.anatomy.mesh.node_sets["midsagittal"]
            surf = self.anatomy.contact_surfaces
            self._contours = tuple(aperture.midsagittal_edges(surf[k], mid)
                                   for k in ("upper_lip", "lower_lip"))
            if not all(len(c) for c in self._contours):
                raise ParameterError("a lip contact surface has no mid-sagittal edge")
        return self._contours

    @property
    def regions(self):
        """muscle -> brick indices within its stiffening radius of its fibres (driven
        muscles; computed once)."""
        if not hasattr(self, "_regions"):
            self._regions = muscle_neighbourhoods(self.anatomy, self.muscles,
                                                  self.properties.stiffening_radius)
        return self._regions

    def region_strains(self, u=None):
        """muscle -> (most compressive, most tensile) logarithmic principal strain over
        the bricks of its region."""
        u = self.model.u if u is None else u
        out = {}
        for m, bricks in self.regions.items():
            eps = log_principal_strains(self.anatomy.mesh, u, bricks)
            out[m] = (float(eps.min()), float(eps.max())) if len(bricks) else (0.0, 0.0)
        return out

    @property
    def term_names(self):
        return [t.name for t in self.model.terms]

    # The step's inputs (activations, jaw pose) are written here alone: their targets by
    # set_activations and set_jaw (values checked by solver.app.simulation.Simulation, the
    # API), committed or rolled back by end_step, restored by restore_inputs.
    def set_activations(self, values):
        """values: dict muscle -> target activation in [0, 1] (checked by the caller)."""
        self.activation.set(values)

    def set_jaw(self, pose):
        """Target jaw pose (opening deg, protrusion mm; checked by the caller, Jaw.pose)."""
        self.jaw.target = np.array(pose, dtype=float).reshape(2)
        self._prescribe_jaw()

    def _prescribe_jaw(self):
        """The mandible's prescribed displacements at the jaw's target pose."""
        self.model.prescribe(self.jaw.geometry.nodes, self.jaw.displacement(self.jaw.target))

    def end_step(self, converged):
        """After a solve or a transient step: commit the targets (activations, jaw pose) as
        the converged state, or on failure put them back to the last converged one."""
        if converged:
            self.activation.commit()
            if self.jaw is not None:
                self.jaw.commit()
            return
        self.activation.target = self.activation.start.copy()
        if self.jaw is not None and np.any(self.jaw.target != self.jaw.start):
            self.jaw.target = self.jaw.start.copy()
            self._prescribe_jaw()

    def restore_inputs(self, activation, pose):
        """Put the activations (10,) and the jaw at pose (opening, protrusion) as the
        converged state, targets equal (a simulation's set_state)."""
        self.activation.start = np.array(activation, dtype=float).reshape(-1)
        self.activation.target = self.activation.start.copy()
        self.set_jaw_state(pose)

    def set_jaw_state(self, pose):
        """Put the jaw at pose (opening, protrusion) as the converged state (set_state)."""
        if self.jaw is None:
            return
        self.jaw.start = np.array(pose, dtype=float).reshape(2)
        self.jaw.target = self.jaw.start.copy()
        self._prescribe_jaw()

    def incisor_opening(self):
        """mm: how far the mandible's incisor point has moved (solver.face.jaw); 0 without a
        jaw."""
        return 0.0 if self.jaw is None else self.jaw.geometry.incisor_opening(self.jaw.start)

    def solve_static(self, steps=2, relax=True, **kw):
        """Load-stepped equilibrium at the target activations and jaw pose; where that
        fails and ``relax``, the equilibrium the damped face settles into
        (solver.core.transient.relax: past the limit points of a folding lip and the cycling
        of contact); res.relaxation is its RelaxResult (None when load stepping
        sufficed). On failure the displacements, the activations and the jaw stay at the
        last converged state."""
        res = self.model.solve_static(steps=steps, **kw)
        res.relaxation = None
        if not res.converged and relax:
            rel = relax_to_equilibrium(self.model)
            res.relaxation = rel
            if rel.converged:
                res.converged, res.reason = True, ""
                res.displacement = self.model.u.copy()
            else:
                res.reason = f"{res.reason}; then {rel.reason}"
        self.end_step(res.converged)
        return res

    @property
    def u(self):
        return self.model.u

    def lip_outputs(self, u=None):
        """Lip measures (mm) for displacements u (n, 3) (default: the current state).

        lip_aperture          smallest distance between the lips in the mid-sagittal
                              plane, 0 when they touch (solver/face/aperture.py)
        upper/lower_lip_protrusion  forward (y) displacement of each lip's front point
        lip_protrusion        their mean
        lip_width             distance between the mouth corners (2 |x| on a half face)
        """
        u = self.model.u if u is None else u
        lm = self.anatomy.landmarks
        x = self.anatomy.mesh.nodes + u
        out = {"lip_aperture": aperture.contour_gap(x[:, 1:], *self.lip_contours)}
        out["upper_lip_protrusion"] = float(u[lm["upper_lip_front"], 1])
        out["lower_lip_protrusion"] = float(u[lm["lower_lip_front"], 1])
        out["lip_protrusion"] = 0.5 * (out["upper_lip_protrusion"] + out["lower_lip_protrusion"])
        if "corner_right" in lm:
            out["lip_width"] = float(np.linalg.norm(x[lm["corner_right"]] - x[lm["corner_left"]]))
        else:
            out["lip_width"] = float(2.0 * abs(x[lm["corner_left"], 0]))
        return out
