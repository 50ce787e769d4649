"""Time to first step of the built FMU through fmpy: cold (empty numba cache), cold after
compiling the kernels on all cores first, and warm.

    python benchmarks/fmu_startup.py [--fmu dist/FaceFMU.fmu] [--jobs N] [--md FILE]

Each start runs in a fresh process (instantiate and initialize at the FMU's defaults, one
5 ms doStep). cold: an empty NUMBA_CACHE_DIR, which the FMU fills at its initialization
(on all cores where the host is a Python interpreter, else at the first calls); cold,
compiled first: an empty one filled by `python -m solver.app.warm --jobs N`
(default: the CPUs) before the FMU's process starts, as examples/cosim_speech.py does;
warm: a cache that holds the kernels. Prints each, in one call; --md writes them as a
table with the command and commit.
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


def compile_first(cache, jobs):
    """Seconds of `python -m solver.app.warm` filling cache."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "solver.app.warm", "--quiet"]
                   + (["--jobs", str(jobs)] if jobs else []), env=env, check=True,
                   capture_output=True, cwd=ROOT)
    return time.perf_counter() - t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fmu", default=str(ROOT / "dist" / "FaceFMU.fmu"))
    ap.add_argument("--jobs", type=int, default=None,
                    help="processes of the compilation first (default: the CPUs)")
    ap.add_argument("--md", default="", help="write the table to this file")
    args = ap.parse_args(argv)
    rows = []

    def row(label, first, init, step, total):
        rows.append((label, first, init, step, total))
        print(f"{label}: " + (f"compilation {first:.2f} s, " if first else "")
              + f"initialization {init:.2f} s, first doStep {step:.2f} s, process total "
              f"{total:.2f} s; {first + total:.2f} s in all", flush=True)
    with tempfile.TemporaryDirectory() as cache:
        row("cold: the FMU compiles the kernels at initialization", 0.0,
            *start(args.fmu, cache))
        row("warm: the kernels cached", 0.0, *start(args.fmu, cache))
    with tempfile.TemporaryDirectory() as cache:
        first = compile_first(cache, args.jobs)
        row("cold, compiled first on all cores", first, *start(args.fmu, cache))
    if args.md:
        sys.path.insert(0, str(ROOT))
        from solver.app.provenance import command, stamp
        lines = [f"Written by `{command('benchmarks/fmu_startup.py', argv)}` {stamp()}, "
                 f"{os.cpu_count()} cores: FaceFMU at its defaults through fmpy, each start "
                 "a fresh process (seconds).", "",
                 "| start | compilation first | instantiate and initialize | first doStep "
                 "| in all |", "|---|---|---|---|---|"]
        for label, first, init, step, total in rows:
            lines.append(f"| {label} | {first:.1f} | {init:.1f} | {step:.1f} | "
                         f"{first + total:.1f} |")
        Path(args.md).write_text("\n".join(lines) + "\n")
        print(f"wrote {args.md}")

if __name__ == "__main__":
    main()
