"""The paper's Table 4 and the run that measures ours.

Table 4 of Nazari, Perrier, Chabanas and Payan: orbicularis oris peripheralis (OOP)
activated over 0.1 s in a transient analysis; the largest compressive strain of the OOP
region at 0.02 s (the paper's row "0 to 0.02 s"), 0.03 s, ..., 0.1 s, and a largest average
compressive strain rate of about -6.5 1/s.

Ours: the built-in scene `table4_oop` (OOP ramped from a = 0 to 1 over 0.1 s), every 0.01 s;
strain: the most compressive logarithmic principal strain over the bricks of the paper's
OOP region (the reference face's `OOP_region`, from OOP_elements.txt) or, on a face
without that set, of OOP's stiffening neighbourhood. Rate: (eps(t) - eps(t - 0.01)) /
0.01; average rate: eps(t) / t.
"""

import time

import numpy as np

from solver.core.strain import log_principal_strains

# (t (s), largest compressive strain): the paper's Table 4
TABLE4 = ((0.02, -0.13), (0.03, -0.19), (0.04, -0.27), (0.05, -0.33), (0.06, -0.41),
          (0.07, -0.45), (0.08, -0.51), (0.09, -0.55), (0.10, -0.56))
TABLE4_AVG_RATE = -6.5      # 1/s, the paper's largest average compressive strain rate
TABLE4_TOLERANCE = 0.03     # strain: how close every row must come


def paper_strain(t):
    """The paper's Table 4 strain at t (s), None where it gives none."""
    for tp, eps in TABLE4:
        if abs(tp - t) < 1e-9:
            return eps
    return None


def oop_region(anatomy, sim):
    """Brick indices (k,) over which Table 4's strain is measured: the anatomy's
    'OOP_region' set, else OOP's stiffening neighbourhood in sim's face."""
    region = anatomy.mesh.element_sets.get("OOP_region")
    if region is not None and len(region):
        return region
    return sim.face.regions["OOP"]


def table4_run(anatomy, until=0.1, **overrides):
    """Run the scene table4_oop on anatomy (solver.face.anatomy.Anatomy) with Scene overrides
    (e.g. sigma_max, calibration) to t = until (s; the paper's 0.1, or a shorter check);
    returns (rows, wall seconds): one dict per 0.01 s with time, strain, rate, avg_rate,
    lip_aperture, lip_protrusion (mm), substeps, newton_iterations, cutbacks. A step that
    fails raises RuntimeError."""
    from solver.app.simulation import Simulation
    sim = Simulation("table4_oop", loaded_anatomy=anatomy, **overrides)
    region = oop_region(anatomy, sim)
    rows, prev, t0 = [], 0.0, time.perf_counter()
    for k in range(1, int(round(until / 0.01)) + 1):
        t = round(0.01 * k, 10)
        sim.set_activations(sim.scene.activations(t))
        stats = sim.step(t)
        if not stats.converged:
            raise RuntimeError(f"table4_oop: the step to {t} s failed: {stats.reason}")
        eps = float(log_principal_strains(anatomy.mesh, sim.face.u, region).min())
        out = sim.outputs()
        rows.append({"time": t, "strain": eps, "rate": (eps - prev) / 0.01, "avg_rate": eps / t,
                     "lip_aperture": out["lip_aperture"], "lip_protrusion": out["lip_protrusion"],
                     "substeps": stats.substeps, "newton_iterations": stats.newton_iterations,
                     "cutbacks": stats.cutbacks})
        prev = eps
    return rows, time.perf_counter() - t0


def row_errors(rows):
    """(k,) ours minus the paper's strain at the paper's rows that rows (table4_run's)
    reach."""
    ours = {round(r["time"], 6): r["strain"] for r in rows}
    return np.array([ours[round(t, 6)] - eps for t, eps in TABLE4 if round(t, 6) in ours])
