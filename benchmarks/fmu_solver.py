"""The full-order model through the FMU, by linear solver: wall time, outputs and exit code.

    python benchmarks/fmu_solver.py [--fmu FILE.fmu] [--fidelity balanced] [--duration 0.1]
                                    [--solvers pardiso-single,superlu] [--repeat 2] [--instances 1]

Each run is a fresh process that calls fmpy.simulate_fmu on the FMU (built here with
build_fmu.py unless --fmu) with the scene written here (transient, lip and teeth contact,
`[solver] linear_solver` the run's) at the fidelity given, OOP 0 -> 1 and RIS 0 -> 0.5
over --duration, outputs every 10 ms. The solvers alternate (one run of each, --repeat
times), so that the machine's drift touches them alike; --instances N: N simulate_fmu
calls (N instances, one after the other) in each process. Prints per run: wall time of
the calls, the last lip aperture and protrusion, and the process's exit code (non-zero: it
crashed, after its work where the outputs are printed; pythonfmu's FMUs corrupt the heap
at the exit of processes that made many instances now and then, tests/conftest.py).
"""

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from benchmarks.table import report  # noqa: E402

RUN = r"""
import json, sys, time
import numpy as np
from fmpy import simulate_fmu
fmu, scene, fidelity, duration = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
instances = int(sys.argv[5])
signals = np.array([(0.0, 0.0, 0.0), (duration, 1.0, 0.5)],
                   dtype=[("time", float), ("OOP", float), ("RIS", float)])
t0 = time.perf_counter()
for _ in range(instances):
    res = simulate_fmu(fmu, stop_time=duration, output_interval=0.01, input=signals,
                       start_values={"scene": scene, "fidelity": fidelity},
                       output=["lip_aperture", "lip_protrusion"])
print(json.dumps({"wall_s": time.perf_counter() - t0,
                  "aperture_mm": f"{res['lip_aperture'][-1]:.5f}",
                  "protrusion_mm": f"{res['lip_protrusion'][-1]:.5f}"}), flush=True)
"""

SCENE = """[scene]
name = "fmu_solver_{solver}"
analysis = "transient"
duration = {duration}

[effects]
lip_contact = true
teeth_contact = true

[solver]
linear_solver = "{solver}"
"""


def run(fmu, folder, solver, fidelity, duration, instances=1):
    """One fresh fmpy process: a row of figures."""
    scene = Path(folder) / f"{solver}.toml"
    scene.write_text(SCENE.format(solver=solver, duration=duration))
    out = subprocess.run([sys.executable, "-c", RUN, str(fmu), str(scene), fidelity,
                          str(duration), str(instances)], capture_output=True, text=True)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    row = {"solver": solver, "exit_code": out.returncode}
    row.update(json.loads(lines[-1]) if lines else {"wall_s": "-", "aperture_mm": "-",
                                                     "protrusion_mm": "-"})
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fmu", type=Path, help="a built FMU (default: build one)")
    ap.add_argument("--fidelity", default="balanced")
    ap.add_argument("--duration", type=float, default=0.1)
    ap.add_argument("--solvers", default="pardiso-single,superlu")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--instances", type=int, default=1)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        fmu = args.fmu
        if fmu is None:
            subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", folder],
                           check=True, capture_output=True)
            fmu = Path(folder) / "FaceFMU.fmu"
        rows = []
        for _ in range(args.repeat):
            for solver in args.solvers.split(","):
                rows.append(run(fmu, folder, solver, args.fidelity, args.duration,
                                args.instances))
                print(f"  {rows[-1]}", flush=True)
    print(f"\nfidelity {args.fidelity}, {args.duration} s gesture through fmpy.simulate_fmu, "
          f"{args.instances} instance(s) per process (wall times; the machine may be shared)")
    report(rows, ["solver", "wall_s", "aperture_mm", "protrusion_mm", "exit_code"])
    return 1 if any(r["exit_code"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
