"""Numba kernels: single-purpose, compiled once and cached on disk (see solver._cache)."""

from .. import _cache  # noqa: F401  (sets the cache directory before any compile)
