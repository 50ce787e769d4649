"""Numba kernels: single-purpose, compiled once and cached on disk (see solver.core._cache)."""

from solver.core import _cache  # noqa: F401  (sets the cache directory before any compile)
