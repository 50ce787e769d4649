"""Build dist/FaceFMU.fmu: the slave script with the solver and facefmu packages bundled.

    python build_fmu.py [--dest dist] [--rom FILE.npz ...] [--with-realtime]

The FMU runs in the importer's Python (needsExecutionTool="false"): numpy, scipy, numba
(and pypardiso where available) must be installed there; resources/requirements.txt lists
them. canGetAndSetFMUstate and canSerializeFMUstate are on.

Reduced-order (`fidelity = "realtime"`) models: --rom packs trained model files
(solver.rom.store, e.g. from ~/.cache/facefmu/rom) into the FMU's resources/rom, where the
slave looks first; --with-realtime packs the cached model of the built-in `speech` scene
(all ten muscles, lip and teeth contact: `python benchmarks/rom_train.py` trains it).

The FMU's linux64 binary is pythonfmu's C++ wrapper corrected (facefmu.wrapper): pythonfmu
0.7.0's own corrupts the heap of the importer's process at its exit. Where the corrected
one cannot be built (no compiler or headers, no sdist, not Linux x86_64, a pythonfmu other
than 0.7.0) the build says why on stderr and keeps pythonfmu's; --stock-wrapper keeps it
deliberately and --require-patched-wrapper makes that an error. --fix-wrapper X.fmu puts
the corrected wrapper into other FMUs that pythonfmu built.
"""

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from facefmu.wrapper import WrapperUnavailable, patched_wrapper, replace_wrapper

ROOT = Path(__file__).resolve().parent
REQUIREMENTS = """numpy>=1.26
scipy>=1.11
numba>=0.59
threadpoolctl>=3.5
pypardiso>=0.4.6; platform_machine == 'x86_64'
"""

def realtime_model(scene="speech"):
    """The cached realtime model file of a scene (built-in name or TOML path); SystemExit
    naming the training command when there is none."""
    sys.path.insert(0, str(ROOT))
    from solver.app.fidelity import apply_fidelity
    from solver.rom.store import model_path
    from solver.app.simulation import resolve_scene
    path = model_path(apply_fidelity(resolve_scene(scene), "realtime"))
    if not path.is_file():
        raise SystemExit(f"no trained realtime model of scene {scene!r} at {path}; train "
                         f"it with: python benchmarks/rom_train.py --scene {scene}")
    return path


def build(dest=ROOT / "dist", roms=(), wrapper="patched"):
    """Build FaceFMU.fmu into dest; roms: model files (.npz) packed into resources/rom.
    wrapper: "patched" (the corrected wrapper where it can be built, else pythonfmu's, with
    the reason on stderr), "required" (the corrected one or SystemExit) or "stock"."""
    from pythonfmu.builder import FmuBuilder
    corrected = None
    if wrapper != "stock":
        try:
            corrected = patched_wrapper()
        except WrapperUnavailable as exc:
            if wrapper == "required":
                raise SystemExit(f"no corrected pythonfmu wrapper: {exc}")
            print(f"build_fmu: WARNING: pythonfmu's own wrapper kept ({exc}); processes "
                  "that run this FMU can abort at exit (docs/dev-notes/exit-crash.md)",
                  file=sys.stderr)
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
        files = [tmp / "solver", tmp / "facefmu", tmp / "requirements.txt"]
        if roms:
            sys.path.insert(0, str(ROOT))
            from solver.rom.store import file_name, load_model
            (tmp / "rom").mkdir()
            for path in roms:
                path = Path(path)
                if not path.is_file():
                    raise SystemExit(f"--rom {path}: no such file")
                # filed under its key's name, where the slave looks for the scene's model
                shutil.copy2(path, tmp / "rom" / file_name(load_model(path)[1]["key"]))
            files.append(tmp / "rom")
        sys.path.insert(0, str(tmp))
        try:
            fmu = FmuBuilder.build_FMU(
                script, dest=dest / "FaceFMU.fmu", project_files=files,
                needsExecutionTool="false", canGetAndSetFMUstate="true",
                canSerializeFMUstate="true")
        finally:
            sys.path.remove(str(tmp))
    if corrected is not None:
        replace_wrapper(fmu, corrected)
    return Path(fmu)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dest", default=str(ROOT / "dist"))
    ap.add_argument("--rom", action="append", default=[], metavar="FILE.npz",
                    help="a trained realtime model to pack into resources/rom (repeatable)")
    ap.add_argument("--with-realtime", action="store_true",
                    help="pack the cached realtime model of the built-in 'speech' scene")
    group = ap.add_mutually_exclusive_group()
    group.add_argument("--stock-wrapper", action="store_true",
                       help="keep pythonfmu's own C++ wrapper (its importers can abort at "
                            "exit: docs/dev-notes/exit-crash.md)")
    group.add_argument("--require-patched-wrapper", action="store_true",
                       help="fail where the corrected wrapper cannot be built")
    ap.add_argument("--fix-wrapper", nargs="+", metavar="FMU",
                    help="instead of building FaceFMU: put the corrected wrapper into these "
                         "FMUs built by `pythonfmu build` (any pythonfmu 0.7.0 FMU)")
    args = ap.parse_args(argv)
    if args.fix_wrapper:
        try:
            wrapper = patched_wrapper()
        except WrapperUnavailable as exc:
            if args.require_patched_wrapper:
                raise SystemExit(f"no corrected pythonfmu wrapper: {exc}")
            print(f"build_fmu: WARNING: pythonfmu's own wrapper kept ({exc}); processes "
                  "that run these FMUs can abort at exit (docs/dev-notes/exit-crash.md)",
                  file=sys.stderr)
            return
        for fmu in args.fix_wrapper:
            replace_wrapper(fmu, wrapper)
            print(fmu)
        return
    roms = list(args.rom) + ([realtime_model()] if args.with_realtime else [])
    wrapper = ("stock" if args.stock_wrapper else
               "required" if args.require_patched_wrapper else "patched")
    print(build(args.dest, roms, wrapper))


if __name__ == "__main__":
    main()
