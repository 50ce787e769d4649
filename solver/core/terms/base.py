"""The term interface: every physical effect adds to the residual and the tangent.

A term declares its element blocks once (node connectivities for the sparsity pattern)
and then, for each state, adds its forces and stiffness:

    class MyTerm(Term):
        name = "my_effect"
        def blocks(self) -> list of (k, nloc) int arrays
        def assemble(self, state, asm, block_ids) -> None

``state`` carries u (n, 3) and the load factor; ``asm`` is a solver.core.assembly.Assembly
(add_block, residual, energy, need_k). A term raises InvertedElement when the state is
not admissible, so that Newton's line search or the load stepping can back off.
Terms that hold a load path (prescribed values that ramp with the load factor) implement
``commit()``, called when a load step has converged. A term whose blocks follow the
converged state (contact candidates) changes them in ``commit()`` or ``follow_state(u)`` and
increments its ``blocks_generation``: the System then rebuilds its sparsity pattern.
"""

from dataclasses import dataclass, field

import numpy as np


class InvertedElement(Exception):
    """A state with det F <= 0 somewhere; carries the worst element and its det F."""

    def __init__(self, term, element, jmin):
        self.term, self.element, self.jmin = term, element, jmin
        super().__init__(f"{term}: element {element} has det F = {jmin:.3g}")


@dataclass
class State:
    """A point of the load path: u (n, 3) mm, load factor lam in [0, 1], time t (s)."""

    u: np.ndarray
    lam: float = 1.0
    t: float = 0.0
    extra: dict = field(default_factory=dict)


class Term:
    """Base class; see the module docstring."""

    name = "term"
    nonsmooth = False       # its force switches on and off (contact); then touching():
                            # (n,) bool, the nodes it pushed on at its last evaluation
    blocks_generation = 0   # incremented when blocks() change

    def blocks(self):
        return []

    def assemble(self, state, asm, block_ids):
        raise NotImplementedError

    def commit(self, state):
        """Called once a load step (or time step) has converged at state."""


def pack_parts(parts):
    """(k,) int64: the integer arrays parts, each after its length (their count first):
    how a pattern state of several blocks travels as one array (unpack_parts reads it)."""
    parts = [np.asarray(p, dtype=np.int64).ravel() for p in parts]
    return np.concatenate([np.array([len(p) for p in parts], dtype=np.int64), *parts])


def unpack_parts(data, n, what):
    """The n integer arrays that pack_parts wrote into data; ValueError naming `what` when
    data cannot hold n of them."""
    data = np.asarray(data, dtype=np.int64).ravel()
    lens = data[:n]
    if len(data) < n or np.any(lens < 0) or n + lens.sum() != len(data):
        raise ValueError(f"{what}: {len(data)} numbers do not hold {n} packed arrays")
    return np.split(data[n:], np.cumsum(lens)[:-1]) if n else []
