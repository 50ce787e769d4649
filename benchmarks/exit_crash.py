"""Reproducer of issue 35: processes that hosted pythonfmu FMUs through fmpy abort at exit.

    python benchmarks/exit_crash.py [--fmu mix|face|cosim|lipmc|triv|numpy] [--runs 30]
        [--instances 1] [--steps 3] [--fail-init] [--no-terminate] [--no-free]
        [--logging] [--wrapper built|stock|patched|FILE.so] [--env KEY=VALUE ...]
        [--seeds] [--cores] [--valgrind] [--main-job N] [--keep DIR]

The acceptance campaign (prints the counts, exits 1 on any abort):

    python benchmarks/exit_crash.py --fmu mix --runs 100 --main-job 30

Builds the FMU(s) once into a temporary folder (FaceFMU with build_fmu.py, the others
with `pythonfmu build`), extracts each once, then runs --runs fresh child processes, ONE
AT A TIME. Each child instantiates --instances instances one after the other through
fmpy's FMU2Slave (instantiate, setupExperiment, initialization, --steps doSteps,
terminate, freeInstance), prints "ok" and returns normally, so the interpreter's teardown
runs. Prints the counts of exit codes; a child that printed "ok" and then died is an
abort at exit.

--fmu: mix (run i takes the i-th of MIX, in turn: FaceFMU alone with one and with two
  instances, FaceFMU with the controller beside it with one and two pairs, and FaceFMU
  failing initialization beside a good instance), face (build_fmu.py, its default
  fidelity, 1 ms steps), cosim (FaceFMU and the
  LipMotorControl example FMU stepped together, as examples/cosim_speech.py does), lipmc
  (the controller alone), triv (a one-variable slave, no numpy), numpy (a slave that
  imports numpy, scipy.sparse.linalg and numba and steps a jitted function).
--fail-init: every second instance fails exitInitializationMode (a Python exception in
  the slave: FaceFMU gets a scene that does not exist, the test slaves a `fail`
  parameter), i.e. the path where pythonfmu's wrapper turns an exception into fmi2Fatal;
  freeInstance follows as usual.
--wrapper: which libpythonfmu-export.so all the extracted FMUs run: the one each was built
  with (built: FaceFMU gets build_fmu.py's corrected wrapper where it can be built, the
  `pythonfmu build` FMUs pythonfmu's), pythonfmu's own as installed (stock: 0.7.0's,
  which aborts), the corrected one (patched: facefmu.wrapper.patched_wrapper(), built if
  absent), or a file.
--env KEY=VALUE: set in the children (e.g. MALLOC_PERTURB_=165, which fills freed memory
  so that a use after free shows; MALLOC_CHECK_=3 needs
  LD_PRELOAD=/usr/lib/x86_64-linux-gnu/libc_malloc_debug.so.0 on glibc >= 2.34).
--seeds: run i gets PYTHONHASHSEED=i+1 (else random): the heap's history, and so whether a
  use after free ends in an abort, then repeats more closely between wrappers.
--valgrind: one child under valgrind's memcheck instead of --runs children; prints the
  invalid reads and writes of the wrapper (finalizePythonInterpreter, onLibraryUnload)
  with the stack where the memory was freed (--fmu triv keeps it short).
--main-job N: then run the README's main job (examples/cosim_speech.py) N times, each
  into a fresh folder, and count its exit codes.
--cores: children may dump core (into the run's folder); the first core's gdb
  backtrace is printed.
"""

import argparse
import collections
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONTROL = ROOT / "examples" / "motor_control"

# the test slaves' variables: an output x and a fixed parameter fail
VARIABLES = '''\
        self.x, self.fail = 0.0, 0.0
        self.register_variable(Real("x", causality=Fmi2Causality.output))
        self.register_variable(Real("fail", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed))
'''

TRIV = '''
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class Triv(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
''' + VARIABLES + '''
    def exit_initialization_mode(self):
        if self.fail:
            raise ValueError("fail parameter set")

    def do_step(self, t, dt):
        self.x += dt
        return True
'''

NUMPY = '''
import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


@numba.njit(cache=False)
def _relax(u, h):
    for i in range(u.size):
        u[i] += h * (1.0 - u[i])
    return u


class Numpy(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
''' + VARIABLES + '''        self.u = np.zeros(200)
        n = 200
        self.a = sp.diags([-np.ones(n - 1), 4 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1],
                          format="csc")
        self.lu = None

    def exit_initialization_mode(self):
        if self.fail:
            raise ValueError("fail parameter set")
        self.lu = spla.splu(self.a)

    def do_step(self, t, dt):
        _relax(self.u, dt)
        self.x = float(self.lu.solve(self.u).sum())
        return True

    def terminate(self):
        self.lu = None
'''

CHILD = r'''
import sys
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

kind, instances, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
fail_init, terminate, free, logging = (a == "1" for a in sys.argv[4:8])
dirs = dict(a.split("=", 1) for a in sys.argv[8:])
MUSCLES = ("LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM")
OUTPUTS = ("lip_aperture", "lip_protrusion", "lip_width")


def start(name, instance, params=()):
    d = dirs[name]
    md = read_model_description(d)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d,
                    modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName=f"{name}{instance}")
    fmu.instantiate(loggingOn=logging)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    for key, value in params:
        (fmu.setString if isinstance(value, str) else fmu.setReal)([vr[key]], [value])
    try:
        fmu.exitInitializationMode()
        ok = True
    except FMICallException:
        ok = False
    return fmu, vr, ok


def finish(fmu, ok=True):
    if terminate and ok:            # after fmi2Fatal only fmi2FreeInstance is allowed
        fmu.terminate()
    if free:
        fmu.freeInstance()


kept = []                       # instances not freed stay referenced to the end
for k in range(instances):
    failing = fail_init and k % 2 == 1
    if kind == "cosim":
        face, fv, ok1 = start("face", k, [("scene", "no_such_scene")] if failing else [])
        ctrl, cv, ok2 = start("lipmc", k)
        t, h = 0.0, 0.005
        for _ in range(steps if ok1 else 0):
            y = face.getReal([fv[o] for o in OUTPUTS])
            acts = ctrl.getReal([cv[m] for m in MUSCLES])
            ctrl.getString([cv["phoneme"]])
            ctrl.setReal([cv[o] for o in OUTPUTS], y)
            face.setReal([fv[m] for m in MUSCLES], acts)
            ctrl.doStep(t, h)
            face.doStep(t, h)
            t += h
        fmus = [(face, ok1), (ctrl, ok2)]
    else:
        name = kind
        params = []
        if failing:
            params = [("scene", "no_such_scene")] if kind == "face" else [("fail", 1.0)]
        fmu, vr, ok = start(name, k, params)
        h = 0.001 if kind == "face" else 0.005
        if kind == "face" and ok:
            fmu.setReal([vr["OOP"]], [0.5])
        for i in range(steps if ok else 0):
            fmu.doStep(i * h, h)
        fmus = [(fmu, ok)]
    for f, ok in fmus:
        finish(f, ok)
    kept += fmus
print("ok", flush=True)
'''


# --fmu mix: (kind, instances, fail_init) of run i, in turn
MIX = (("face", 1, False), ("face", 2, False), ("cosim", 1, False), ("cosim", 2, False),
       ("face", 2, True))
NEEDS = {"cosim": ("face", "lipmc"), "mix": ("face", "lipmc")}


def build(kinds, dest):
    """Build the FMUs that kinds need into dest; {name: fmu path}. The controller gets the
    corrected wrapper as examples/cosim_speech.py builds it; triv and numpy keep
    pythonfmu's own (pass --wrapper patched to correct them)."""
    names = set()
    for kind in kinds:
        names.update(NEEDS.get(kind, (kind,)))
    out = {}
    quiet = dict(check=True, stdout=subprocess.DEVNULL)
    if "face" in names:
        subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", str(dest)],
                       cwd=dest, **quiet)
        out["face"] = dest / "FaceFMU.fmu"
    if "lipmc" in names:
        subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f",
                        str(CONTROL / "lip_motor_control.py"), "-d", str(dest),
                        "--no-external-tool", str(CONTROL / "lipmc_inverse.py"),
                        str(CONTROL / "inverse_model.json")], cwd=CONTROL, **quiet)
        out["lipmc"] = dest / "LipMotorControl.fmu"
        subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--fix-wrapper",
                        str(out["lipmc"])], **quiet)
    for name, source, cls in (("triv", TRIV, "Triv"), ("numpy", NUMPY, "Numpy")):
        if name in names:
            src = dest / "src" / f"exitcrash_{name}.py"
            src.parent.mkdir(exist_ok=True)
            src.write_text(source)
            subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(src),
                            "-d", str(dest), "--no-external-tool"], cwd=src.parent, **quiet)
            out[name] = dest / f"{cls}.fmu"
    return out


def patched_wrapper():
    """The corrected wrapper (facefmu.wrapper; built now if absent)."""
    from facefmu.wrapper import patched_wrapper as build
    return build()


def extract(fmus, dest, wrapper=None):
    """Extract each FMU once into dest/NAME; with wrapper, its .so replaces the FMU's."""
    from fmpy import extract as fmpy_extract
    dirs = {}
    for name, path in fmus.items():
        d = dest / name
        fmpy_extract(str(path), str(d))
        if wrapper is not None:
            for so in (d / "binaries" / "linux64").glob("*.so"):
                shutil.copy2(wrapper, so)
        dirs[name] = d
    return dirs


def backtrace(core):
    out = subprocess.run(["gdb", "-batch", "-ex", "bt", sys.executable, str(core)],
                         capture_output=True, text=True).stdout
    return "\n".join(l for l in out.splitlines() if l.startswith("#"))


def run_valgrind(cmd, env, base):
    """One child under memcheck; prints the wrapper's invalid accesses; 1 if any."""
    if shutil.which("valgrind") is None:
        raise SystemExit("valgrind is not installed")
    log = base / "valgrind.log"
    env = dict(env, PYTHONMALLOC="malloc")
    t0 = time.perf_counter()
    p = subprocess.run(["valgrind", "--tool=memcheck", f"--log-file={log}", *cmd], env=env,
                       cwd=base, capture_output=True, text=True, timeout=3600)
    text = re.sub(r"^==\d+== ?", "", log.read_text(), flags=re.M)
    errors = [b.strip() for b in text.split("\n\n") if b.lstrip().startswith("Invalid")
              and ("finalizePythonInterpreter" in b or "onLibraryUnload" in b)]
    print(f"valgrind memcheck, exit {p.returncode} ({time.perf_counter() - t0:.0f} s), "
          f"log {log}: {len(errors)} invalid access(es) in pythonfmu's wrapper")
    for e in errors:
        print(e, "\n")
    return 1 if errors else 0


def main_job(n, env, base):
    """Run examples/cosim_speech.py n times into fresh folders; the number that failed."""
    counts, t0 = collections.Counter(), time.perf_counter()
    for i in range(n):
        out = base / "main_job" / str(i)
        p = subprocess.run([sys.executable, str(ROOT / "examples" / "cosim_speech.py"),
                            "--out", str(out)], env=env, capture_output=True, text=True,
                           timeout=1800)
        met = re.search(r"^all \d+ targets met", p.stdout, re.M) is not None
        counts[(p.returncode, met)] += 1
        print(f"main job {i + 1}/{n}: exit {p.returncode}"
              f"{', all targets met' if met else ''}", flush=True)
        if p.returncode:
            print(p.stderr[-800:])
    print(f"\n{n} runs of examples/cosim_speech.py ({time.perf_counter() - t0:.0f} s):")
    for (code, met), k in sorted(counts.items()):
        print(f"  exit code {code:4d}: {k:3d}"
              f"{'' if code else ', all targets met' if met else ''}")
    return sum(k for (code, _), k in counts.items() if code != 0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fmu", default="face",
                    choices=("mix", "face", "cosim", "lipmc", "triv", "numpy"))
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--instances", type=int, default=1)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--fail-init", action="store_true")
    ap.add_argument("--no-terminate", action="store_true")
    ap.add_argument("--no-free", action="store_true")
    ap.add_argument("--logging", action="store_true", help="instantiate with loggingOn")
    ap.add_argument("--wrapper", default="built",
                    help="built, stock, patched or the path of a libpythonfmu-export.so")
    ap.add_argument("--env", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--seeds", action="store_true", help="PYTHONHASHSEED=i+1 in run i")
    ap.add_argument("--cores", action="store_true")
    ap.add_argument("--valgrind", action="store_true")
    ap.add_argument("--main-job", type=int, default=0, metavar="N")
    ap.add_argument("--keep", help="build and extract into this folder (reused if there)")
    args = ap.parse_args(argv)

    wrapper = {"built": None}.get(args.wrapper, args.wrapper)
    if wrapper == "patched":
        wrapper = patched_wrapper()
    elif wrapper == "stock":
        import pythonfmu
        wrapper = (Path(pythonfmu.__file__).parent / "resources" / "binaries" / "linux64"
                   / "libpythonfmu-export.so")
    tmp = None
    if args.keep:
        base = Path(args.keep).resolve()
        base.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.TemporaryDirectory(prefix="exit-crash-")
        base = Path(tmp.name)
    try:
        build_dir = base / "fmus"
        build_dir.mkdir(exist_ok=True)
        t0 = time.perf_counter()
        needed = NEEDS.get(args.fmu, (args.fmu,))
        fmus = {n: build_dir / f for n, f in (("face", "FaceFMU.fmu"),
                                              ("lipmc", "LipMotorControl.fmu"),
                                              ("triv", "Triv.fmu"), ("numpy", "Numpy.fmu"))
                if n in needed and (build_dir / f).is_file()}
        if set(fmus) != set(needed):
            fmus = build([args.fmu], build_dir)
        tag = "built" if wrapper is None else args.wrapper if args.wrapper in (
            "stock", "patched") else Path(wrapper).stem
        x_dir = base / "extracted" / tag
        if x_dir.exists():
            shutil.rmtree(x_dir)
        x_dir.mkdir(parents=True)
        dirs = extract(fmus, x_dir, wrapper)
        print(f"built and extracted {', '.join(sorted(fmus))} in "
              f"{time.perf_counter() - t0:.1f} s; wrapper: {wrapper or 'as built'}")

        env = dict(os.environ)
        env.pop("PYTHONFAULTHANDLER", None)
        for item in args.env:
            key, value = item.split("=", 1)
            env[key] = value
        def child(i):
            kind, instances, fail_init = (MIX[i % len(MIX)] if args.fmu == "mix" else
                                          (args.fmu, args.instances, args.fail_init))
            flags = (fail_init, not args.no_terminate, not args.no_free, args.logging)
            return [sys.executable, "-c", CHILD, kind, str(instances), str(args.steps),
                    *("1" if flag else "0" for flag in flags),
                    *(f"{n}={d}" for n, d in dirs.items())]

        if args.valgrind:
            return run_valgrind(child(0), env, base)

        def limits():
            if args.cores:
                resource.setrlimit(resource.RLIMIT_CORE, (resource.RLIM_INFINITY,
                                                          resource.RLIM_INFINITY))

        counts, messages, core = collections.Counter(), collections.Counter(), None
        t0 = time.perf_counter()
        for i in range(args.runs):
            run_dir = base / "runs" / str(i)
            run_dir.mkdir(parents=True, exist_ok=True)
            if args.seeds:
                env["PYTHONHASHSEED"] = str(i + 1)
            p = subprocess.run(child(i), env=env, cwd=run_dir, capture_output=True, text=True,
                               preexec_fn=limits, timeout=900)
            finished = "ok" in p.stdout.splitlines()
            key = (p.returncode, finished)
            counts[key] += 1
            if p.returncode:
                last = [l for l in p.stderr.splitlines() if l.strip()]
                messages[last[-1][:100] if last else "(nothing on stderr)"] += 1
            if p.returncode and not finished:
                print(f"run {i}: exit {p.returncode} before 'ok':\n{p.stderr[-1500:]}")
            cores = sorted(run_dir.glob("core*"))
            if cores and core is None:
                core = cores[0]
                keep = base / "core"
                shutil.move(core, keep)
                core = keep
            for c in cores[1:] if core else cores:
                if c.exists():
                    c.unlink()
            print(f"run {i + 1}/{args.runs}: exit {p.returncode}"
                  f"{'' if finished else ' (did not finish)'}", flush=True)
        wall = time.perf_counter() - t0
        print(f"\n{args.runs} fresh processes of --fmu {args.fmu} --instances {args.instances} "
              f"--steps {args.steps}{' --fail-init' if args.fail_init else ''}"
              f"{' --no-terminate' if args.no_terminate else ''}"
              f"{' --no-free' if args.no_free else ''}{' --logging' if args.logging else ''}"
              f"{' --seeds' if args.seeds else ''}"
              f", wrapper {args.wrapper}{', env ' + ' '.join(args.env) if args.env else ''}"
              f" ({wall:.0f} s):")
        for (code, finished), n in sorted(counts.items()):
            what = "clean exit" if code == 0 else (
                "died after 'ok' (at exit)" if finished else "died before 'ok'")
            print(f"  exit code {code:4d}: {n:3d}  {what}")
        for text, n in messages.most_common():
            print(f"  {n:3d} x stderr: {text}")
        if core is not None:
            print(f"\nbacktrace of the first core ({core}):\n{backtrace(core)}")
        aborted = sum(n for (code, _), n in counts.items() if code != 0)
        if args.main_job:
            aborted += main_job(args.main_job, env, base)
        return 1 if aborted else 0
    finally:
        if tmp is not None:
            tmp.cleanup()


if __name__ == "__main__":
    sys.exit(main())
