"""The face's physical effects as terms of the core's interface
(solver.core.terms.base.Term): muscle cables, activation stiffening, lip and teeth
contact."""
