r"""The reduced operator: forces and tangents of a face model in reduced coordinates.

This is the reference implementation of the fast online step (solver.rom.online: the
same quantities, checked against it by tests/test_rom_online.py), also used in training.

With the basis V (3 n, r) (orthonormal on the free DOFs, zero rows on the constrained
ones) the displacements are u = V q + L(p), L the jaw's prescribed motion at its pose p
(solver.rom.lifting; 0 with the jaw closed). Backward Euler from (q_n, v_n) with step h, the
same scheme as the full model (solver.core.transient), projected (Galerkin):

    R(q) = M_r (q - q_n - h v_n) / h^2 + C_r (q - q_n) / h
           + f_bricks(q, a) + f_cables(q, a) + f_contact(q) = 0,
    dR/dq = M_r / h^2 + C_r / h + K_bricks + K_cables + K_contact,

* inertia: M_r = V^T M V (lumped M, exact);
* damping: C_r = alpha M_r + beta V^T K_n V, K_n the passive tissue's small-strain
  stiffness on the shape at the start of the substep by the cubature
  (passive_stiffness), as the full model (solver/core/terms/inertia.py); or the constant rest
  one, K_0 (damping "rest"). A moving jaw adds beta V^T K_n (L(p) - L(p_n)) / h
  (lifting_damping). The stepping (solver.rom.stepper) decides when it is built;
  the fast online step (solver.rom.online) applies it matrix-free;
* tissue and activation stiffening: the ECSW cubature (solver.rom.ecsw) over the selected
  bricks, sum_e w_e V_e^T (f_e + s_e(a) f^s_e) (solver.rom.kernels);
* cables (all, exactly): cable c pulls its end points x_p, x_q, with
  x_q - x_p = d0_c(p) + D_c q, D_c = sum_a (w_qa V_a - w_pa V_a) (3, r); with l, n, the
  tension T = AE (l / L0 - 1 + e_c(a))^+ (solver.core.kernels.cable):
  f_r = sum_c T D_c^T n, K_r = sum_c D_c^T (AE/L0 n n^T + T/l (I - n n^T)) D_c;
* contact (reduced contact): the penalty contact terms themselves (solver.face.terms.contact),
  evaluated on displacements reconstructed at their slave and master nodes only, their
  element forces and tangents projected with the rows of V of those nodes:
  f_r = sum_b V_b^T f_b, K_r = sum_b V_b^T K_b V_b.
"""

import numpy as np

from solver.core.assembly import block_dofs
from solver.core.terms.base import State
from solver.rom.kernels import reduced_bricks
from solver.rom.lifting import Lifting


class _Capture:
    """An Assembly stand-in for the contact terms: keeps their element blocks."""

    def __init__(self, need_k):
        self.need_k, self.energy, self.blocks = need_k, 0.0, []

    def add_block(self, block, fe, ke=None, rows=None):
        self.blocks.append((block, fe, ke, rows))


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
        self._contact_setup()
        self.fr, self.kr = np.zeros(self.r), np.zeros((self.r, self.r))
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

    def _contact_setup(self):
        self.cblocks = []              # per term, per block: (k, 3 nloc, r) basis rows
        nodes = []
        for term in self.contact:
            bl = term.blocks()
            self.cblocks.append([np.ascontiguousarray(
                self.V[block_dofs(b)]) for b in bl])
            nodes += [np.asarray(b).ravel() for b in bl]
        self.cnodes = np.unique(np.concatenate(nodes)) if nodes else np.zeros(0, np.int64)
        self.Vc = np.ascontiguousarray(self.Vn[self.cnodes])
        self._uc = np.zeros((self.mesh.n_nodes, 3))

    # -- evaluation ----------------------------------------------------------------------
    def bricks_part(self, q, a, need_k):
        """(f_r, K_r or None, min det F) of the cubature at q for activations a (10,)."""
        s = self.stiffening_factors(a)
        jmin = reduced_bricks(q, self.Ve, self.le, self.weights, self.dndX, self.wgp,
                              self.params,
                              self.form, self.sparams, s, need_k, self.fr, self.kr)
        return self.fr.copy(), (self.kr.copy() if need_k else None), jmin

    def cables_part(self, q, a, need_k):
        if self.ncab == 0:
            return np.zeros(self.r), (np.zeros((self.r, self.r)) if need_k else None)
        d = self.d0 + self.D @ q                                   # (c, 3)
        l = np.sqrt((d * d).sum(axis=1))
        n = d / l[:, None]
        s = l / self.L0 - 1.0 + a[self.cab_muscle] * self.cab_unit
        on = s > 0.0
        T = np.where(on, self.AE * s, 0.0)
        self.tension = T
        Dn = np.einsum("cir,ci->cr", self.D[on], n[on])            # (c_on, r)
        f = Dn.T @ T[on]
        if not need_k:
            return f, None
        Ton, lon = T[on], l[on]
        # D^T (AE/L0 - T/l) n n^T D + T/l D^T D
        K = (Dn.T * ((self.AE[on] / self.L0[on]) - Ton / lon)) @ Dn
        Dw = self.D[on] * np.sqrt(Ton / lon)[:, None, None]
        K += np.einsum("cir,cis->rs", Dw, Dw)
        return f, K

    def reconstruct_contact(self, q):
        """(n, 3) displacements filled at the contact nodes only (zero elsewhere)."""
        self._uc[self.cnodes] = self.Vc @ q + self.L[self.cnodes]
        return self._uc

    def contact_part(self, q, need_k, t=0.0):
        f = np.zeros(self.r)
        K = np.zeros((self.r, self.r)) if need_k else None
        if not self.contact:
            return f, K
        st = State(self.reconstruct_contact(q), self.lam, t, {})
        for term, vb in zip(self.contact, self.cblocks):
            cap = _Capture(need_k)
            term.assemble(st, cap, list(range(len(vb))))
            for block, fe, ke, rows in cap.blocks:
                Vb = vb[block] if rows is None else vb[block][rows]
                if len(Vb) == 0:
                    continue
                if rows is None:                     # all slaves: keep the active ones
                    on = np.flatnonzero(np.abs(fe).max(axis=1) > 0)
                    Vb, fe = Vb[on], fe[on]
                    ke = ke[on] if ke is not None else None
                if len(Vb) == 0:
                    continue
                Vf = Vb.reshape(-1, self.r)
                f += Vf.T @ fe.ravel()
                if need_k and ke is not None:
                    K += Vf.T @ (ke @ Vb).reshape(-1, self.r)
        return f, K

    def forces(self, q, a, need_k, t=0.0):
        """Internal forces (no inertia, damping): (f_r, K_r or None, min det F)."""
        fb, kb, jmin = self.bricks_part(q, a, need_k)
        fc, kc = self.cables_part(q, a, need_k)
        fk, kk = self.contact_part(q, need_k, t)
        f = fb + fc + fk
        return f, (kb + kc + kk if need_k else None), jmin

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
