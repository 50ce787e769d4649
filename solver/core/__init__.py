"""The finite-element core: meshes, the hexahedral element, hyperelastic materials,
assembly, load-stepped Newton, linear solvers, implicit time stepping and the generic
terms (elasticity, inertia and damping, loads, gravity), with their numba kernels.

It knows no face: nothing here imports solver.face, solver.app, solver.rom or
solver.validation (tests/test_layers.py reads the imports to check it)."""
