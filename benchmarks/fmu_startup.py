"""Time to first step of the built FMU through fmpy: cold (empty numba cache) and warm.

    python benchmarks/fmu_startup.py [--fmu dist/FaceFMU.fmu]

Each start runs in a fresh process (instantiate, initialize on the coarse generic half
face, one 5 ms doStep); cold uses an empty NUMBA_CACHE_DIR, warm reuses it. Prints both.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SNIPPET = """
import time, sys
t0 = time.perf_counter()
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
path = sys.argv[1]
md = read_model_description(path)
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path),
                modelIdentifier=md.coSimulation.modelIdentifier, instanceName='x')
fmu.instantiate(); fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode(); fmu.exitInitializationMode()
t1 = time.perf_counter()
fmu.doStep(0.0, 0.005)
t2 = time.perf_counter()
print(f"{t1 - t0:.2f} {t2 - t1:.2f}")
fmu.terminate(); fmu.freeInstance()
"""


def start(fmu, cache):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", SNIPPET, str(fmu)], env=env, check=True,
                         capture_output=True, text=True).stdout.split()
    return float(out[0]), float(out[1]), time.perf_counter() - t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fmu", default=str(ROOT / "dist" / "FaceFMU.fmu"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as cache:
        for label in ("cold", "warm", "warm"):
            init, step, total = start(args.fmu, cache)
            print(f"{label}: initialization {init:.2f} s, first doStep {step:.2f} s, "
                  f"process total {total:.2f} s")


if __name__ == "__main__":
    main()
