"""Validation used by tests and benchmarks: the hard cases and their invariants
(stability), and the paper's Table 4 measurement (paper)."""
