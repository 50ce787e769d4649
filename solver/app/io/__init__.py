"""Input and output: meshio export of anatomies and results (pictures: solver.app.plot)."""

from solver.app.io.export import (export_anatomy, fibre_displacements,
                                   green_lagrange_strain, principal_strains)

__all__ = ["export_anatomy", "fibre_displacements", "green_lagrange_strain",
           "principal_strains"]
