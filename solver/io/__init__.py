"""Input and output: meshio export of anatomies and results (pictures: solver.plot)."""

from .export import (export_anatomy, fibre_displacements, green_lagrange_strain,
                     principal_strains)

__all__ = ["export_anatomy", "fibre_displacements", "green_lagrange_strain",
           "principal_strains"]
