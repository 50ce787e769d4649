r"""Newton directions with the current contact tangent on a reused factorization
(``NewtonOptions.krylov``): GMRES preconditioned by the factorization.

A reused factorization A holds the smooth terms' tangent of an earlier iterate and the
contact terms' tangent C_A of the iterate where it was made. Modified Newton's direction
A^-1 (-r) lacks the contact's change since, C(u_k) - C_A, which on a lip gesture is
what slows the iteration (docs/dev-notes/fast_path.md: a pressed slave is a stiff
spring whose direction turns with every step). Here the direction solves

    (A + D) du = c,    D = C(u_k) - C_A + U diag(d) U^T,    c = -r - U (d * p)

on the free DOFs, where the rank-one terms U diag(d) U^T and U (d * p) correct for the
contact status that the step itself predicts, against the status at u_k (as
solver.core.contact_update does against the factorization's: slave i is active after the
step when p_i + v_i . du > 0, columns U = v_i of the slaves that change, d_i = +k_i for
one that comes into contact and -k_i for one that leaves; repeated until the set
settles). D is supported on the contact's DOFs and is assembled sparse (its entries that
differ from zero); A is only solved with, never multiplied.

Right-preconditioned GMRES: du = a du_0 + Z y with du_0 = A^-1 c (the plain modified
Newton step, or the last round's direction) and Z = A^-1 V, V the Arnoldi basis of the
residual's Krylov space; (A + D) z_j = v_j + D z_j: one solve and one product with D per
iteration, and the direction from the kept Z without another solve. du_0's coefficient
a is free (du_0 joins the augmentation space below, with A du_0 known, and the iteration
starts from zero): with a = 1 fixed the start's linear residual is -D du_0, many times
||c|| where a step carries a slave into contact (a penalty's stiffness), and more
directions use up their budget of solves (docs/dev-notes/fast_path.md). The iteration
stops when ||c - (A + D) du|| <= rtol ||c|| (the product A Z taken as V: to the
factorization's precision). Where it does not within maxiter, no direction is returned and Newton
refactorizes.

rtol is Newton's forcing term (an inexact Newton direction): the residual and the
convergence criteria are Newton's own, so it moves the converged state only within
Newton's tolerance (why 0.1: docs/dev-notes/fast_path.md).

Recycling (GCRO augmentation): the pairs (Z, A Z) solved for earlier directions on the
same factorization (at most ``recycle``, the newest) span most of what the next, nearby D
needs. The residual is first minimized over span((A + D) Z) = span(A Z + D Z), which
costs products with D and a QR, no solve; the Arnoldi vectors that follow are kept
orthogonal to that span, and the new pairs join the kept ones. Newton uses these
directions only where the reused factorization's plain one would not do (solver.core.newton).
"""

import numpy as np
import scipy.sparse as sp


class KrylovDirection:
    """The contact terms of a system and where their tangent lives in its CSR data.

    system   solver.core.system.System with nonsmooth terms (contact)
    rtol     GMRES's relative tolerance on the linear residual
    maxiter  solves per direction at most, over all rounds (no restart)
    rounds   status predictions at most
    recycle  solved directions kept per factorization for later directions (GCRO)
    """

    @classmethod
    def of(cls, system):
        """The one for system's current constraints (built once: the gather of the
        contact's entries costs a sort over the pattern)."""
        kept = system.helpers.get("krylov")
        if kept is None or kept[0] is not system.reduction:
            kept = (system.reduction, cls(system))
            system.helpers["krylov"] = kept
        return kept[1]

    def __init__(self, system, rtol=0.1, maxiter=12, rounds=4, recycle=30):
        self.rtol, self.maxiter, self.rounds, self.recycle = rtol, maxiter, rounds, recycle
        self.terms = [t for t in system.terms if callable(getattr(t, "linear_gaps", None))]
        pattern = system.pattern
        ids = [b for t, bs in zip(system.terms, system._ids) if t.nonsmooth for b in bs]
        idx = np.unique(np.concatenate([pattern.index[b].ravel() for b in ids])) \
            if ids else np.zeros(0, dtype=np.int64)
        rows = np.searchsorted(pattern.indptr, idx, side="right") - 1
        self.index = -np.ones(system.ndof, dtype=np.int64)      # DOF -> free DOF or -1
        self.index[system.free] = np.arange(len(system.free))
        fr, fc = self.index[rows], self.index[pattern.indices[idx]]
        keep = (fr >= 0) & (fc >= 0)
        self.idx, self.rows, self.cols = idx[keep], fr[keep], fc[keep]
        self.nf = len(system.free)
        self.system = system
        self.solved = 0                # GMRES iterations (solves), summed
        self.failed = 0                # directions not found within maxiter

    def __bool__(self):
        return len(self.idx) > 0

    def mark(self, lin, contact_data):
        """Record on lin the contact terms' tangent (CSR data (nnz,)) that its new
        factorization holds."""
        lin.notes["krylov_base"] = (contact_data[self.idx].copy(), [])

    def _base(self, lin):
        """(contact tangent, recycled [(Z, AZ)]) of lin's factorization, or None."""
        return lin.notes.get("krylov_base")

    def _recycled(self, kept):
        """(Z, AZ) of the newest kept solves, at most self.recycle of them, or None."""
        if not kept:
            return None
        Z = np.concatenate([z for z, _ in kept])[-self.recycle:]
        return Z, np.concatenate([a for _, a in kept])[-self.recycle:]

    def direction(self, lin, u, r):
        """du (ndof,) at u (ndof,) with residual r (ndof,) on lin's reused factorization,
        or None where lin has no recorded contact tangent or GMRES did not converge."""
        found = self._base(lin)
        if found is None:
            return None
        base, kept = found
        delta = self.system.nonsmooth_tangent(u)[self.idx] - base
        nz = delta != 0.0
        Dc = sp.csr_matrix((delta[nz], (self.rows[nz], self.cols[nz])),
                           shape=(self.nf, self.nf))
        gaps = [t.linear_gaps(u.reshape(-1, 3)) for t in self.terms]
        free = self.system.free
        b = -r[free]
        du, Adu, chosen, start = None, None, None, self.solved
        for _ in range(self.rounds + 1):
            U, d, p = self._changes(gaps, du)
            key = U.indices.tobytes() + np.sign(d).tobytes() if U is not None else b""
            if key == chosen:
                break
            chosen = key
            if U is None:
                D, c = Dc, b
            else:
                D = Dc + U @ sp.diags(d) @ U.T
                c = b - U @ (d * p)
            if du is None:
                du = _plain(lin, r)
                if du is None:
                    du = np.asarray(lin.solve(c)).ravel()
                    self.solved += 1
                Adu = c.copy()
            du, Adu, n, new = gmres(lin.solve, D, c, du, Adu, self.rtol,
                                    self.maxiter - (self.solved - start), self._recycled(kept))
            self.solved += n
            if len(new[0]):
                kept.append(new)
                kept[:] = kept[-self.recycle:]
            if du is None:
                self.failed += 1
                return None
        out = np.zeros(self.system.ndof)
        out[free] = du
        return out

    def _changes(self, gaps, du):
        """(U (nf, m) sparse, d (m,), p (m,)) of the slaves whose status after the step du
        (free DOFs; None: no step yet, the status at u) differs from the status at u,
        or (None, None, None)."""
        cols, ds, ps = [], [], []
        for g in gaps:
            if g is None or du is None:
                continue
            dofs, v, k, p = g
            f = self.index[dofs]
            step = np.where(f >= 0, du[np.maximum(f, 0)], 0.0)
            want = p + (v * step).sum(axis=1) > 0.0
            for i in np.flatnonzero(np.isfinite(p) & (want != (p >= 0.0))):
                keep = f[i] >= 0
                cols.append((f[i][keep], v[i][keep]))
                ds.append(k[i] if want[i] else -k[i])
                ps.append(p[i])
        if not cols:
            return None, None, None
        ptr = np.cumsum([0] + [len(c[0]) for c in cols])
        U = sp.csc_matrix((np.concatenate([c[1] for c in cols]),
                           np.concatenate([c[0] for c in cols]), ptr),
                          shape=(self.nf, len(cols)))
        return U, np.array(ds), np.array(ps)


def _plain(lin, r):
    """A^-1 (-r_f) where Newton solved it already on lin's current factorization (its
    plain direction, solver.core.newton._direction, kept in lin.notes), else None."""
    kept = lin.notes.get("plain")
    if kept is None or kept[0] is not r:
        return None
    return np.asarray(kept[1]).ravel().copy()


def gmres(solve, D, c, du0, Adu0, rtol, m, recycled=None):
    """Right-preconditioned GMRES for (A + D) du = c with A known by its solves, augmented
    by a recycled space (GCRO).

    solve      x = A^-1 b for b (n,)
    D          (n, n) sparse
    c          (n,) right-hand side
    du0, Adu0  (n,) start and A du0 (du0 = A^-1 c: Adu0 = c)
    recycled   (Z (k, n), AZ (k, n)) or None: directions with their products by A (kept
               from earlier solves with the same factorization)
    Returns (du, A du, solves, (Z_new, AZ_new)): du minimizes ||c - (A + D) du|| over
    du0 + span(Z) + A^-1 (the Krylov space of the residual left), to rtol ||c||; du is
    None where m solves do not reach it.
    """
    r0 = c - Adu0 - D @ du0
    goal = rtol * float(np.linalg.norm(c))
    n = len(c)
    none = (np.zeros((0, n)), np.zeros((0, n)))
    if float(np.linalg.norm(r0)) <= goal:
        return du0, Adu0, 0, none
    Zr, AZr = recycled if recycled is not None and len(recycled[0]) else none
    # du0 joins the augmentation space with a free coefficient, and the iteration starts
    # from zero (module docstring): no solve more, and ||c - (A + D) du|| <= ||c|| from
    # the start where D du0 is large (a slave's contact switching). (A + D) Z = AZ + D Z
    # = Q R, columns of rank-deficient directions (a zero du0) dropped.
    Zr, AZr = np.vstack([Zr, du0[None]]), np.vstack([AZr, Adu0[None]])
    Q, R = np.linalg.qr((AZr + (D @ Zr.T).T).T)
    keep = np.abs(np.diag(R)) > 1e-12 * np.abs(np.diag(R)).max()
    Zr, AZr, Q, R = Zr[keep], AZr[keep], Q[:, keep], R[np.ix_(keep, keep)]
    qr0 = Q.T @ c
    r1 = c - Q @ qr0
    beta = float(np.linalg.norm(r1))
    if beta <= goal:
        y = np.linalg.solve(R, qr0)
        return y @ Zr, y @ AZr, 0, none
    if m <= 0:
        return None, None, 0, none
    V, Z = np.zeros((m + 1, n)), np.zeros((m, n))
    H, B = np.zeros((m + 1, m)), np.zeros((Q.shape[1], m))
    V[0] = r1 / beta
    e1 = np.zeros(m + 1)
    e1[0] = beta
    for j in range(m):
        Z[j] = np.asarray(solve(V[j])).ravel()
        w = V[j] + D @ Z[j]
        B[:, j] = Q.T @ w
        w -= Q @ B[:, j]
        for i in range(j + 1):                  # modified Gram-Schmidt
            H[i, j] = V[i] @ w
            w -= H[i, j] * V[i]
        H[j + 1, j] = float(np.linalg.norm(w))
        y, *_ = np.linalg.lstsq(H[:j + 2, :j + 1], e1[:j + 2], rcond=None)
        res = float(np.linalg.norm(e1[:j + 2] - H[:j + 2, :j + 1] @ y))
        if res <= goal or H[j + 1, j] == 0.0:
            k = j + 1
            yr = np.linalg.solve(R, qr0 - B[:, :k] @ y)
            du = y @ Z[:k] + yr @ Zr
            Adu = y @ V[:k] + yr @ AZr
            return du, Adu, k, (Z[:k], V[:k])
        V[j + 1] = w / H[j + 1, j]
    return None, None, m, (Z, V[:m])
