r"""Contact status changes as low-rank updates of a factorized tangent (Newton's
``NewtonOptions.contact_update``; issue 10's incremental contact active set).

On the pure penalty law a slave in contact adds k v v^T to the tangent, v = grad p its
penetration's gradient (solver.core.kernels.contact_linear), so the tangent of one contact
status differs from that of another by a sum of rank-one terms. A Newton direction
du = -A^-1 r on a factorized A (made at an iterate whose active slaves were S_A) is
corrected for the status that the step itself predicts: slave i is active after the step
when its linearized penetration p_i + v_i . du > 0, and its force is then k_i (p_i + v_i .
du) v_i, else 0. The slaves whose predicted status differs from S_A are the columns of U
(v_i on the free DOFs; a slave that leaves with the v_i of the iterate where A was made,
whose stiffness A holds), with D = diag(+-k_i) (+ where a slave comes into contact, - where
it leaves); the residual r holds the forces k_i p_i v_i of the slaves active at the
iterate (p_i >= 0), so those whose predicted status differs from that one (the set R; on a
new factorization the same slaves as U's, on a reused one not) add or drop theirs:

    (A + U D U^T) du = c,    c = b - sum_R (+-k_i) p_i u_i,    b = -r,
    (A + U D U^T)^-1 c = y - Z (D^-1 + U^T Z)^-1 U^T y,    y = A^-1 c,   Z = A^-1 U,

with y = du_0 - sum_R (+-k_i) p_i A^-1 u_i (du_0 = A^-1 b, the uncorrected step):
Sherman-Morrison-Woodbury, one solve with as many right-hand sides as new slaves (the
solved columns A^-1 u_i are kept for the factorization's later directions).
The prediction is repeated with the corrected step until the set stops changing (at most
``rounds`` times). Without it a slave that is free at the iterate but pressed by the step
meets no contact stiffness, is carried deep into the master, and the line search cuts the
step short at the first new contact. The residual and the convergence criteria are
unchanged: only the direction is, so the solution is the same to the Newton tolerance.
For a removed slave D^-1 + v^T A^-1 v = -1 / (k (1 + k c)) (c = v^T K^-1 v over the rest of
the tangent): the update stays well conditioned, and A + U D U^T positive definite where
the rest of the tangent is. Smoothed laws (smoothing > 0) have no jump in stiffness and
take no update.
"""

import numpy as np


class ContactUpdate:
    """The contact terms of a system (those with ``linear_gaps``) and the status that the
    current factorization of a linear solver was made with."""

    def __init__(self, system, rounds=4):
        self.terms = [t for t in system.terms if callable(getattr(t, "linear_gaps", None))]
        self.free = system.free
        self.index = -np.ones(system.ndof, dtype=np.int64)        # DOF -> free DOF or -1
        self.index[system.free] = np.arange(len(system.free))
        self.rounds = rounds
        self.corrections = 0          # slaves corrected, summed over directions
        self.changed = []             # of the last direction: [((term, slave), active)]
        self.settled = False          # whether its predicted status reproduced itself
        self._marked = None           # (u, gaps at u) of the last mark

    def __bool__(self):
        return bool(self.terms)

    def _gaps(self, u):
        """[(dofs (s, m), v (s, m), k (s,), p (s,)) or None] of each term at u (ndof,)."""
        return [t.linear_gaps(u.reshape(-1, 3)) for t in self.terms]

    def mark(self, lin, u):
        """Record on lin the active slaves at u, where its new factorization was made, with
        their gradients (the stiffness k v v^T that the factorization holds), and start its
        cache of solved columns (the gaps at u are kept for the direction that follows at
        the same u)."""
        self._marked = (u, self._gaps(u))
        lin.notes["contact_status"] = (
            [None if g is None else g[3] >= 0 for g in self._marked[1]], {}, self._marked[1])

    def _status(self, lin):
        """(base masks, column cache, gaps at the mark) of lin's current factorization, or
        None."""
        return lin.notes.get("contact_status")

    def correct(self, lin, u, du):
        """du (ndof,) corrected for the predicted status (the module docstring), or du
        itself where lin's factorization has no recorded status."""
        status = self._status(lin)
        if status is None:
            return du
        base, cache, at_mark = status
        marked = self._marked
        gaps = marked[1] if marked is not None and marked[0] is u else self._gaps(u)
        du0, out, chosen = du[self.free], du, None
        self.settled = False
        for rnd in range(self.rounds + 1):
            # the matrix: predicted status against the factorization's (a slave that it
            # holds leaves with the gradient it was factorized with); the right-hand side:
            # against the status at u, whose forces r holds. Entries ((term, slave, which
            # gradient: 0 the mark's, 1 u's), d_i, p_i, dofs, v)
            mat, rhs = [], []
            for t, (g, act, g0) in enumerate(zip(gaps, base, at_mark)):
                if g is None:
                    continue
                dofs, v, k, p = g
                want = p + (v * out[dofs]).sum(axis=1) > 0.0
                ok = np.isfinite(p)
                for i in np.flatnonzero(ok & act & ~want):
                    mat.append(((t, i, 0), -k[i], p[i], g0[0][i], g0[1][i]))
                for i in np.flatnonzero(ok & want & ~act):
                    mat.append(((t, i, 1), k[i], p[i], dofs[i], v[i]))
                for i in np.flatnonzero(ok & (want != (p >= 0.0))):
                    rhs.append(((t, i, 1), k[i] if want[i] else -k[i], p[i], dofs[i], v[i]))
            keys = ([(c[0], c[1] > 0) for c in mat], [(c[0], c[1] > 0) for c in rhs])
            if keys == chosen:
                self.settled = True
                break
            if rnd == self.rounds:
                break                   # out solves the model of the last sets tried
            chosen = keys
            out = du.copy()
            if mat or rhs:
                try:
                    out[self.free] = self._woodbury(lin, cache, du0, mat, rhs)
                except np.linalg.LinAlgError:   # a singular model: no correction
                    chosen, out = None, du
                    break
        self.changed = chosen[0] if chosen else []
        self.corrections += len(self.changed)
        return out

    def _columns(self, lin, cache, sel):
        """[(free DOFs, v_i there, A^-1 u_i)] of the slaves sel, solved once per
        factorization (cache: (term, slave, which gradient) -> that triple; U keeps the v_i of
        that first solve: it is part of the iteration matrix)."""
        nf = len(self.free)
        new = list({c[0]: c for c in sel if c[0] not in cache}.values())
        if new:
            U = np.zeros((nf, len(new)), order="F")
            rows = []
            for j, c in enumerate(new):
                f = self.index[c[3]]
                keep = f >= 0
                rows.append((f[keep], c[4][keep]))
                U[f[keep], j] = c[4][keep]
            Z = np.asarray(lin.solve(U)).reshape(nf, len(new))
            for j, c in enumerate(new):
                cache[c[0]] = (*rows[j], Z[:, j].copy())
        return [cache[c[0]] for c in sel]

    def _woodbury(self, lin, cache, du0, mat, rhs):
        """(A + U D U^T)^-1 (b - sum_rhs d_i p_i u_i) on the free DOFs (U, D: the slaves
        mat), b = A du0."""
        cols = self._columns(lin, cache, rhs + mat)          # one solve for the new ones
        y = du0.copy()
        for (_, _, z), c in zip(cols, rhs):
            y -= (c[1] * c[2]) * z
        if not mat:
            return y
        cols = cols[len(rhs):]
        Z = np.column_stack([c[2] for c in cols])                      # (nf, m)
        d = np.array([c[1] for c in mat])
        S = np.diag(1.0 / d) + np.array([(v[:, None] * Z[f]).sum(axis=0) for f, v, _ in cols])
        uty = np.array([(v * y[f]).sum() for f, v, _ in cols])
        return y - Z @ np.linalg.solve(S, uty)
