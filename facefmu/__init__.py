"""FaceFMU: the FMI 2.0 co-simulation slave and command-line tools over the solver."""
