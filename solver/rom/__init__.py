r"""Reduced-order model of the face: the `realtime` fidelity (issue 10).

    sim = Simulation(scene, fidelity="realtime")     # the ROM behind Simulation's API
    python benchmarks/rom_train.py --scene SCENE      # train (cached per user)
    python benchmarks/rom_train.py --scene SCENE --accuracy   # held-out gestures

Offline (solver.rom.train): full-order snapshot runs under random activation patterns
(dask tasks), a POD displacement basis V on the free DOFs (solver.rom.pod: u = V q), an
ECSW empirical cubature of the internal forces over a few bricks (solver.rom.ecsw), the
reduced mass and rest stiffness, and a calibrated trust threshold; one .npz per scene key
(solver.rom.store). Online (solver.rom.simulation, solver.rom.reduced): backward Euler in
q with inertia V^T M V, constant damping alpha V^T M V + beta V^T K_0 V, the cubature
bricks (tissue and activation stiffening, solver.rom.kernels), every cable exactly, and
the penalty contact terms evaluated on the displacements of their nodes only and
projected; a periodic full-order residual check that warns or falls back to the full
model when the state leaves the trained range.
"""

from .store import ModelNotTrained, load_model, model_key, model_path, save_model

__all__ = ["ModelNotTrained", "load_model", "model_key", "model_path", "save_model"]
