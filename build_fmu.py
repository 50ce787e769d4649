"""Build dist/FaceFMU.fmu: the slave script with the solver and facefmu packages bundled.

    python build_fmu.py [--dest dist]

The FMU runs in the importer's Python (needsExecutionTool="false"): numpy, scipy, numba
(and pypardiso where available) must be installed there; resources/requirements.txt lists
them. canGetAndSetFMUstate and canSerializeFMUstate are on.
"""

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent
REQUIREMENTS = """numpy>=1.26
scipy>=1.11
numba>=0.59
pypardiso>=0.4.6; platform_machine == 'x86_64'
"""


def build(dest=ROOT / "dist"):
    from pythonfmu.builder import FmuBuilder
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="facefmu-build-") as tmp:
        tmp = Path(tmp)
        ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
        for pkg in ("solver", "facefmu"):
            shutil.copytree(ROOT / pkg, tmp / pkg, ignore=ignore)
        script = tmp / "facefmu_slave.py"
        shutil.move(tmp / "facefmu" / "facefmu_slave.py", script)
        (tmp / "requirements.txt").write_text(REQUIREMENTS)
        sys.path.insert(0, str(tmp))
        try:
            fmu = FmuBuilder.build_FMU(
                script, dest=dest / "FaceFMU.fmu",
                project_files=[tmp / "solver", tmp / "facefmu", tmp / "requirements.txt"],
                needsExecutionTool="false", canGetAndSetFMUstate="true",
                canSerializeFMUstate="true")
        finally:
            sys.path.remove(str(tmp))
    return Path(fmu)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dest", default=str(ROOT / "dist"))
    args = ap.parse_args(argv)
    print(build(args.dest))


if __name__ == "__main__":
    main()
