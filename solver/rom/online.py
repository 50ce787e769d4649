r"""The online reduced operator: solver.rom.reduced.ReducedOperator's forces and tangents,
evaluated fast (same math; tests/test_rom_online.py compares the two).

* bricks: force-only kernel (solver.rom.online_kernels.brick_forces_nodal; tissue and
  stiffening in one pass) on the b distinct nodes of the cubature's bricks, between two
  BLAS products: u_b = V_b q + L_b before, f_r = V_b^T f_b after; the tangent split into
  the tissue's and each brick's unit stiffening (solver.rom.kernels.brick_tangents_split),
  so that a tangent built on one shape follows the activations exactly
  (kt + sum_e s_e(a) ks_e);
* cables: one numba pass (cable_forces_r) over D_c (c, 3, r) projected once (the
  tangent: D^T (W D) in one BLAS product);
* the jaw: the lifting L(p) of the operator's pose (ReducedOperator.set_pose,
  solver.rom.lifting) in every displacement: le in the bricks' kernels, d0(p) of the
  cables, the contact nodes and the lower teeth (ReducedContact.set_pose);
* contact: solver.rom.contact.ReducedContact (the terms' kernels on their nodes only);
* damping (beta K_n, K_n on the shape at the start of the substep, as the full model):
  matrix-free, in the bricks' kernel, on the cubature's bricks (prepare_damping once per
  substep: their dN/dx on that shape); the damping matrix itself (for the tangent only)
  by solver.rom.damping_kernels.passive_stiffness_kv on that shape;
* activations: the stiffening factors s_e and the cables' active strains are computed
  once per substep (set_activation), not per iteration.

forces(q) returns the internal reduced force f_b + f_c + f_k in a work array and keeps the
active sets (taut cables, contact slaves) of that evaluation, which the Newton iteration
(solver.rom.stepper) compares with those of its frozen tangent.
"""

import numpy as np

from solver.core.kernels.material_point import point_response
from solver.rom.contact import ReducedContact
from solver.rom.damping_kernels import damping_geometry, passive_stiffness_kv
from solver.rom.kernels import brick_tangents_split
from solver.rom.online_kernels import brick_forces_nodal, cable_forces_r


def small_strain_tangents(params, form):
    """(D0 (m, 6, 6), kvol (m,)): the tangent of each brick's law (params (m, 6)) at
    C = 1 (with the volumetric part for form 1, 'full') and U''(1) = 2 / d (form 0)."""
    m = len(params)
    D0, S = np.empty((m, 6, 6)), np.empty((3, 3))
    for e in range(m):
        point_response(np.eye(3), np.ascontiguousarray(params[e], dtype=np.float64),
                       form == 1, True, S, D0[e])
    return D0, 2.0 / np.asarray(params, dtype=np.float64)[:, 5]


class OnlineOperator:
    """op: a solver.rom.reduced.ReducedOperator (its arrays are shared, not copied);
    contact_delta (mm): see solver.rom.contact; generic_contact: the terms' assemble()
    (reference path)."""

    def __init__(self, op, contact_delta=0.2, generic_contact=False):
        self.op, self.r = op, op.r
        r = self.r
        self.contact = ReducedContact(op.contact, op.V, op.mesh.n_nodes, contact_delta,
                                      generic_contact)
        self.ncab = op.ncab
        if self.ncab:
            self.D = np.ascontiguousarray(op.D)
            self.AE = np.ascontiguousarray(op.AE, dtype=np.float64)
            self.L0 = np.ascontiguousarray(op.L0, dtype=np.float64)
            self.wd = np.zeros_like(self.D)                 # W_c D_c (c, 3, r)
            self.tension = np.zeros(self.ncab)
        self.fb, self.fc = np.zeros(r), np.zeros(r)
        self.f = np.zeros(r)
        self.s = np.zeros(len(op.bricks))
        self.e = np.zeros(self.ncab)
        self.taut = 0
        self.a = None
        k = len(op.bricks)
        self.D0, self.kvol = small_strain_tangents(op.params, op.form)
        self.dxn, self.wn, self.dvn = np.zeros((k, 8, 8, 3)), np.zeros((k, 8)), np.zeros((k, 24))
        self.ue_n = np.zeros((k, 24))
        # the cubature's distinct nodes: V_b (3 b, r), the bricks' local connectivity
        conn = op.mesh.bricks[op.bricks]
        self.bnodes, local = np.unique(conn, return_inverse=True)
        self.lconn = np.ascontiguousarray(local.reshape(conn.shape), dtype=np.int64)
        self.Vb = np.ascontiguousarray(op.Vn[self.bnodes].reshape(-1, r))
        self.fnod = np.zeros((len(self.bnodes), 3))
        self._lift = (None, None, None, None)        # (op.L_n, L_b,n, L_b, op.L)
        self._kv = np.zeros((k, 24, r))                     # damping_tangent's w_e K_n,e V_e
        self._ve2 = np.ascontiguousarray(op.Ve).reshape(k * 24, r)
        self.bd, self.q_n = 0.0, np.zeros(r)
        # bricks that stiffen with some muscle: their unit-stiffening tangents apart
        stiff = np.flatnonzero(op.sweight.max(axis=1) > 0) if op.stiffening is not None \
            else np.zeros(0, dtype=np.int64)
        self.slot = -np.ones(k, dtype=np.int64)
        self.slot[stiff] = np.arange(len(stiff))
        self.stiff = stiff
        self.kt, self.ks = np.zeros((r, r)), np.zeros((len(stiff), r, r))

    def prepare_damping(self, q_n, bd, start=True, ref=None):
        """The damping force bd V^T K_n (u - u_d) of the coming evaluations: K_n (the
        cubature's passive small-strain stiffness) on the shape X + V q_n + L (L the
        lifting at the substep's start, or with start False its end); u_d that shape, or
        with ref = (q_d (r,), L_d (n, 3)) V q_d + L_d. bd = c beta (0: none). Returns the
        smallest det F of that shape."""
        self.bd, self.q_n = float(bd), q_n
        if not bd:
            return 1.0
        op = self.op
        jmin = damping_geometry(self.nodal(q_n, start=start), self.lconn, op.dndX, op.wgp,
                                self.ue_n, self.dxn, self.wn, self.dvn)
        if ref is not None:
            u_d = (self.Vb @ ref[0]).reshape(-1, 3) + ref[1][self.bnodes]
            self.ue_n[:] = u_d[self.lconn].reshape(len(self.lconn), 24)
        return jmin

    def nodal(self, q, start=False):
        """(b, 3) the displacements V_b q + L_b of the cubature's nodes, L the operator's
        lifting at the end of the substep (at its start: start=True)."""
        op = self.op
        if self._lift[0] is not op.L_n or self._lift[3] is not op.L:
            self._lift = (op.L_n, np.ascontiguousarray(op.L_n[self.bnodes]),
                          np.ascontiguousarray(op.L[self.bnodes]), op.L)
        u = (self.Vb @ q).reshape(-1, 3)
        return u + self._lift[1 if start else 2]

    def set_pose(self):
        """Take the operator's jaw pose (ReducedOperator.set_pose) into the contact."""
        self.contact.set_pose(self.op.pose, self.op.L, self.op.lam)

    def set_activation(self, a):
        """Activations (10,) of the coming evaluations (one substep)."""
        if self.a is not None and np.array_equal(a, self.a):
            return
        self.a = np.array(a, dtype=float)
        self.s = np.ascontiguousarray(self.op.stiffening_factors(self.a))
        if self.ncab:
            self.e = np.ascontiguousarray(self.a[self.op.cab_muscle] * self.op.cab_unit)

    # -- forces ---------------------------------------------------------------------------
    def forces(self, q):
        """(f (r,) the internal reduced force, a work array; min det F of the bricks)."""
        op = self.op
        f = self.f
        jmin = brick_forces_nodal(self.nodal(q), self.lconn, op.weights, op.dndX, op.wgp,
                                  op.params, op.sparams, self.s, op.form, self.ue_n, self.bd,
                                  self.dxn, self.wn, self.dvn, self.D0, self.kvol, self.fnod)
        if not jmin > 0.0:
            return f, jmin
        np.dot(self.fnod.reshape(-1), self.Vb, out=f)
        if self.ncab:
            self.taut = cable_forces_r(q, self.D, self.op.d0, self.AE, self.L0, self.e, False,
                                       True, f, self.wd, self.tension)
        self.contact.evaluate(q, False, f)
        return f, jmin

    def active_sets(self):
        """Signatures (bytes) of the taut cables and of each contact term's active slaves
        in the last evaluation: equal signatures, equal sets."""
        return (self.taut,) + self.contact.active

    @property
    def contact_force(self):
        return self.contact.total_force

    # -- tangents -------------------------------------------------------------------------
    def brick_tangent(self, q):
        """Build the cubature's tangent at q, split as tissue + unit stiffening per brick
        (solver.rom.kernels.brick_tangents_split); False if a brick inverts. The tangent
        at the current activations is then stiffened_tangent()."""
        op = self.op
        jmin = brick_tangents_split(q, op.Ve, op.le, op.weights, op.dndX, op.wgp, op.params,
                                    op.form, op.sparams, self.slot, self.kt, self.ks)
        return bool(jmin > 0.0)

    def damping_tangent(self):
        """(r, r) V^T K_n V by the cubature on the shape of the last prepare_damping (a new
        array; as ReducedOperator.passive_stiffness on that shape)."""
        op = self.op
        passive_stiffness_kv(op.Ve, op.weights, self.dxn, self.wn, self.dvn, self.D0,
                             self.kvol, op.form, self._kv)
        K = self._ve2.T @ self._kv.reshape(-1, self.r)
        return 0.5 * (K + K.T)

    def stiffened_tangent(self):
        """(r, r) the bricks' tangent of the last brick_tangent() at the activations of
        set_activation (a new array): kt + sum_e s_e ks_e."""
        s = self.s[self.stiff]
        on = s > 0.0
        if not on.any():
            return self.kt.copy()
        return self.kt + np.tensordot(s[on], self.ks[on], axes=1)

    def switching_tangent(self, q, part=None):
        """(r, r): the tangent at q of the switching parts (a new array): part None all,
        0 the cables, 1 + i contact term i (solver.rom.contact). Call it at the q of the
        last forces(): the contact's comes from that evaluation."""
        if part is not None and part > 0:
            return self.contact.tangent(part - 1)
        K = np.zeros((self.r, self.r))
        if self.ncab:
            self.taut = cable_forces_r(q, self.D, self.op.d0, self.AE, self.L0, self.e,
                                       True, False, self.fc, self.wd, self.tension)
            K += self.D.reshape(-1, self.r).T @ self.wd.reshape(-1, self.r)
        if part is None:
            _, kk = self.contact.evaluate(q, True)
            K += kk
        return K

    @property
    def parts(self):
        """The number of switching parts (cables, then each contact term)."""
        return 1 + len(self.contact.adapters)
