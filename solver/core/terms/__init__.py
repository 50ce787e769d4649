"""Physical effects as terms: each module holds one effect's energy, forces and tangent
behind the interface of solver.core.terms.base.Term; a model walks its list of terms, so an
effect that is not in the list costs nothing."""
