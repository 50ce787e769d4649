"""Units used everywhere in FaceFMU, stated once.

=========  ==================  ====================================
quantity   unit                note
=========  ==================  ====================================
length     mm
force      N
stress     MPa = N/mm^2        c10, c20, E of cables
energy     mJ = N mm
time       s
mass       tonne = 1e3 kg      so that N = tonne mm / s^2
density    tonne/mm^3          1040 kg/m^3 = 1.04e-9 tonne/mm^3
=========  ==================  ====================================

A consistent set: force = mass * length / time^2 holds with tonne, mm, s, N.
"""


def kg_per_m3(value: float) -> float:
    """Density in kg/m^3 converted to tonne/mm^3."""
    return value * 1e-12


TISSUE_DENSITY = kg_per_m3(1040.0)  # Buchaillard et al. 2009, as used by the face model
