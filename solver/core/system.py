"""A list of terms over one DOF space, with its sparsity pattern and constraints.

The solver walks the terms in order; a term that is not in the list costs nothing.
"""

import time

import numpy as np

from solver.core.assembly import Assembly, Pattern, Reduction
from solver.core.terms.base import State, pack_parts, unpack_parts


class System:
    """terms: list of Term; ndof = 3 n; prescribed DOFs (p,) sorted."""

    def __init__(self, terms, n_nodes, prescribed):
        self.terms = list(terms)
        self.ndof = 3 * n_nodes
        self.n_nodes = n_nodes
        self._build_pattern()
        self.set_constraints(prescribed)
        self.lam = 1.0
        self.t = 0.0
        self.extra = {}
        self.counters = {"assemblies": 0, "residuals": 0, "partial_tangents": 0,
                         "nonsmooth_residuals": 0}
        self.term_seconds = {t.name: 0.0 for t in self.terms}     # time spent in each term
        # what solvers build once per system and constraint set, by name (solver.core.krylov)
        self.helpers = {}

    def _build_pattern(self):
        blocks, self._ids = [], []
        for t in self.terms:
            b = list(t.blocks())
            self._ids.append(list(range(len(blocks), len(blocks) + len(b))))
            blocks += b
        self.pattern = Pattern(self.ndof, blocks)
        self._generations = [getattr(t, "blocks_generation", 0) for t in self.terms]

    def sync(self):
        """Rebuild the sparsity pattern (and the constraint reduction) where a term's
        blocks changed (its blocks_generation); returns whether it did."""
        if [getattr(t, "blocks_generation", 0) for t in self.terms] == self._generations:
            return False
        self._build_pattern()
        self.set_constraints(self.prescribed)
        return True

    def _patterned(self):
        return [t for t in self.terms if callable(getattr(t, "pattern_state", None))]

    def snapshot(self):
        """(k,) int64: the pattern state of the terms whose blocks follow the state (their
        pattern_state(), each after its length), for restore."""
        return pack_parts(t.pattern_state() for t in self._patterned())

    def restore(self, u, snapshot=None):
        """Put the terms whose blocks follow the converged state (follow_state) at u
        (ndof,), as after a commit there, with the pattern of snapshot (a snapshot()
        taken when u was reached; None: a pattern picked at u alone), and sync: a state
        restored (a failed step, set_state) then has the blocks it had when it was
        reached, and repeats its steps exactly."""
        terms = self._patterned()
        if snapshot is None:
            parts = [None] * len(terms)
        else:
            parts = unpack_parts(snapshot, len(terms), "a pattern snapshot of this system")
        for t, part in zip(terms, parts):
            t.set_pattern_state(part)
        st = self.state(u)
        for t in self.terms:
            if callable(getattr(t, "follow_state", None)):
                t.follow_state(st.u)
        return self.sync()

    def set_constraints(self, prescribed):
        self.prescribed = np.asarray(sorted(prescribed), dtype=np.int64)
        mask = np.ones(self.ndof, dtype=bool)
        mask[self.prescribed] = False
        self.free = np.flatnonzero(mask)
        self.reduction = Reduction(self.pattern, self.free)

    def state(self, u):
        return State(u.reshape(-1, 3), self.lam, self.t, self.extra)

    def _run(self, u, need_k, nonsmooth_only=False):
        asm = Assembly(self.pattern, need_k)
        st = self.state(u)
        clock = time.perf_counter
        for term, ids in zip(self.terms, self._ids):
            if nonsmooth_only and not term.nonsmooth:
                continue
            t0 = clock()
            term.assemble(st, asm, ids)
            self.term_seconds[term.name] += clock() - t0
        if not nonsmooth_only:
            self.energy = asm.energy
        return asm

    def assemble(self, u):
        """(r (ndof,), tangent CSR data (nnz,)) at u (ndof,)."""
        self.counters["assemblies"] += 1
        asm = self._run(u, True)
        return asm.residual, asm.data

    def nonsmooth_tangent(self, u):
        """Tangent CSR data (nnz,) of the nonsmooth terms (contact) alone at u (ndof,);
        Newton adds it to the rest of a tangent made earlier (solver.core.newton)."""
        self.counters["partial_tangents"] += 1
        return self._run(u, True, nonsmooth_only=True).data

    def nonsmooth_residual(self, u):
        """The residual (ndof,) of the nonsmooth terms (contact) alone at u (ndof,), for
        Newton's line search (solver.core.newton); zeros where there are none."""
        self.counters["nonsmooth_residuals"] += 1
        return self._run(u, False, nonsmooth_only=True).residual

    def residual(self, u):
        self.counters["residuals"] += 1
        return self._run(u, False).residual

    def external_scale(self):
        """A force scale of the loads (N), for the relative convergence criterion."""
        return max((t.load_scale(self.lam) for t in self.terms if hasattr(t, "load_scale")),
                   default=0.0)

    def commit(self, u):
        st = self.state(u)
        for t in self.terms:
            t.commit(st)
        self.sync()

    def term(self, name):
        for t in self.terms:
            if t.name == name:
                return t
        raise KeyError(name)
