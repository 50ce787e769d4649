r"""The reduced operator's data: a face model's basis, cubature, cables and jaw lifting in
reduced coordinates, which the online step (solver.rom.online, solver.rom.stepper) and
training (solver.rom.train) share.

With the basis V (3 n, r) (orthonormal on the free DOFs, zero rows on the constrained
ones) the displacements are u = V q + L(p), L the jaw's prescribed motion at its pose p
(solver.rom.lifting; 0 with the jaw closed). Galerkin projection of the full model's
terms (the derivation: docs/method.md, 'Reduced-order model'):

* inertia: M_r = V^T M V (lumped M, exact);
* damping: C_r = alpha M_r + beta V^T K_n V, K_n the passive tissue's small-strain
  stiffness on a shape of the substep by the cubature (passive_stiffness), as the full
  model (solver/core/terms/inertia.py); or the constant rest one, K_0 (damping "rest"),
  to which a moving jaw adds beta V^T K_n (L(p) - L(p_n)) / h (lifting_damping);
* tissue and activation stiffening: the ECSW cubature (solver.rom.ecsw) over the selected
  bricks, sum_e w_e V_e^T (f_e + s_e(a) f^s_e): their V_e, parameters and stiffening
  weights (stiffening_factors);
* cables (all, exactly): x_q - x_p = d0_c(p) + D_c q, D_c = sum_a (w_qa V_a - w_pa V_a)
  (3, r), the active strain a_m * cab_unit of each;
* contact: the scene's contact terms, which solver.rom.contact evaluates on their nodes.

tests/rom_reference.py evaluates these forces and tangents the plain way (the general
kernels, the contact terms' own assemble()): the oracle of the fast online step.
"""

import numpy as np

from solver.rom.kernels import reduced_bricks
from solver.rom.lifting import Lifting


class ReducedOperator:
    """The reduced forces of a face Simulation (its terms, anatomy and activations).

    sim: solver.app.simulation.Simulation (transient); V (3 n, r); bricks (k,) the cubature's
    brick indices and weights (k,); M_r, C_r (r, r)."""

    def __init__(self, sim, V, bricks, weights, M_r, C_r):
        face, mesh = sim.face, sim.anatomy.mesh
        self.face, self.mesh = face, mesh
        self.V = np.ascontiguousarray(V)
        self.r = V.shape[1]
        Vn = self.V.reshape(mesh.n_nodes, 3, self.r)
        self.Vn = Vn
        self.M_r, self.C_r = np.asarray(M_r), np.asarray(C_r)
        self.bricks = np.asarray(bricks, dtype=np.int64)
        self.weights = np.ascontiguousarray(weights, dtype=np.float64)
        conn = mesh.bricks[self.bricks]
        self.Ve = np.ascontiguousarray(Vn[conn].reshape(len(self.bricks), 24, self.r))
        el = face.model.elasticity
        self.form = el.form
        self.params = np.ascontiguousarray(el.params[self.bricks])
        self.dndX = np.ascontiguousarray(mesh.dn_dx[self.bricks])
        self.wgp = np.ascontiguousarray(mesh.det_j[self.bricks])
        self._stiffening_setup(face)
        self._cables_setup(face)
        self.contact = list(sim.contact)
        self.lifting = Lifting(face, conn, face.cables)
        self.set_pose((0.0, 0.0), (0.0, 0.0))

    def set_pose(self, pose_n, pose, lam=1.0):
        """The jaw's pose (2,) at the start (pose_n) and the end (pose) of the coming
        substep, at load factor lam of the caller's step: the lifting L, le (k, 24) of the
        cubature's bricks and the cables' d0 at pose; L_n and le_n at pose_n. Returns
        whether either pose differs from the last call's."""
        key = (np.asarray(pose_n, dtype=np.float64).tobytes(),
               np.asarray(pose, dtype=np.float64).tobytes())
        self.lam = float(lam)
        if key == getattr(self, "_pose_key", None):
            return False
        self._pose_key = key
        self.pose = np.array(pose, dtype=np.float64)
        self.L_n, self.le_n, _ = self.lifting.at(pose_n)
        self.L, self.le, d0 = self.lifting.at(pose)
        if d0 is not None:
            self.d0 = d0
        self.moving = bool(np.any(self.le != self.le_n))
        return True

    # -- setup ---------------------------------------------------------------------------
    def _stiffening_setup(self, face):
        k = len(self.bricks)
        self.sparams = np.zeros((k, 6))
        self.sparams[:, 5] = np.inf
        self.sweight = np.zeros((k, 10))               # per muscle, of each selected brick
        st = face.stiffening
        if st is not None:
            pos = {int(b): i for i, b in enumerate(st.subset)}
            for j, b in enumerate(self.bricks):
                i = pos.get(int(b))
                if i is not None:
                    self.sparams[j, 0], self.sparams[j, 2] = st._c[i]
                    self.sweight[j] = st.weight[i]
        self.stiffening = st

    def stiffening_factors(self, a):
        """(k,) s_e = k_e(a) - 1 of the selected bricks (solver.face.terms.stiffening)."""
        if self.stiffening is None:
            return np.zeros(len(self.bricks))
        k = self.face.properties.stiffening_factor(a)
        return (1.0 + self.sweight * (k[None, :] - 1.0)).max(axis=1) - 1.0

    def _cables_setup(self, face):
        cab = face.cables
        if cab is None:
            self.ncab = 0
            return
        nodes = cab.nodes.reshape(-1, 2, 8)
        self.D = (np.einsum("ca,canr->cnr", cab.w[:, 1], self.Vn[nodes[:, 1]])
                  - np.einsum("ca,canr->cnr", cab.w[:, 0], self.Vn[nodes[:, 0]]))
        self.d0 = np.ascontiguousarray(cab.X[:, 1] - cab.X[:, 0])
        self.AE, self.L0 = cab.AE, cab.L0
        props = face.properties
        from solver.face.anatomy.base import MUSCLE_NAMES
        self.cab_muscle = cab.muscle
        # active strain e_c = a_m * (force scale * eps_c) (MuscleProperties.active_strain)
        self.cab_unit = np.array([props.active_strain(MUSCLE_NAMES[m], 1.0)
                                  for m in cab.muscle])
        self.ncab = len(self.L0)

    def passive_stiffness(self, q, dle=None):
        """V^T K_n V by the cubature: the passive tissue's small-strain stiffness on the
        shape X + V q + L(p_n) (as solver.core.terms.inertia.Damping's K_n), (r, r); with
        dle (k, 24), also V^T K_n dle (r,) (a second return)."""
        from solver.core.element import reference_geometry
        conn = self.mesh.bricks[self.bricks]
        x = self.mesh.nodes[conn] + (np.einsum("kdr,r->kd", self.Ve, q)
                                     + self.le_n).reshape(-1, 8, 3)
        loc = np.arange(8 * len(conn)).reshape(-1, 8)
        det, dndx = reference_geometry(x.reshape(-1, 3), loc)
        Ve, r = self.Ve, self.r
        if dle is not None:               # one more column: K_n dle comes with K_n
            Ve, r = np.ascontiguousarray(np.concatenate([Ve, dle[:, :, None]], axis=2)), r + 1
        fr, kr = np.zeros(r), np.zeros((r, r))
        jmin = reduced_bricks(np.zeros(r), Ve, np.zeros_like(self.le), self.weights,
                              np.ascontiguousarray(dndx), np.ascontiguousarray(det),
                              self.params, self.form, self.sparams, np.zeros(len(conn)), True,
                              fr, kr)
        if not jmin > 0.0:
            raise FloatingPointError("an inverted brick in the damping's shape")
        if dle is None:
            return kr
        return kr[:-1, :-1].copy(), kr[:-1, -1].copy()

    def lifting_damping(self, q_n):
        """(r,) V^T K_n (L_e(p) - L_e(p_n)) by the cubature, K_n on the shape at q_n (the
        jaw's velocity times h, damped through the tissue; 0 while the jaw stands)."""
        if not self.moving:
            return np.zeros(self.r)
        return self.passive_stiffness(q_n, np.ascontiguousarray(self.le - self.le_n))[1]

    def displacement(self, q, L=None):
        """(n, 3) full displacements V q + L (L: the lifting at the current pose)."""
        return (self.V @ q).reshape(-1, 3) + (self.L if L is None else L)
