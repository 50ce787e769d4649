r"""Reduced-order model of the face: the `realtime` fidelity (issue 10).

    sim = open_simulation(scene, fidelity="realtime")    # the ROM behind Simulation's API
    python benchmarks/rom_train.py --scene SCENE      # train (cached per user)
    python benchmarks/rom_train.py --scene SCENE --accuracy   # held-out gestures

Offline (solver.rom.train): full-order snapshot runs under random activation patterns
(dask tasks), a POD displacement basis V on the free DOFs (solver.rom.pod: u = V q), an
ECSW empirical cubature of the internal forces over a few bricks (solver.rom.ecsw), the
reduced mass and rest stiffness, and a calibrated trust threshold; one .npz per scene key
(solver.rom.store). Online (solver.rom.simulation, .stepper, .online): backward Euler in
q with inertia V^T M V, damping alpha V^T M V + beta V^T K_n V (K_n on the current shape,
by the cubature), the cubature bricks (tissue and activation stiffening), every cable
exactly, and the penalty contact terms' own kernels on their nodes only (.contact),
projected; modified Newton with a frozen reduced tangent; a periodic full-order residual
check (.trust) that warns or falls back to the full model when the state leaves the
trained range. solver.rom.reduced is the first, slower implementation: the reference.
"""

from solver.rom.store import ModelNotTrained, load_model, model_key, model_path, save_model

__all__ = ["ModelNotTrained", "load_model", "model_key", "model_path", "save_model"]
