"""Compile the solver's numba kernels ahead of the first step, on several cores at once.

A fresh machine has no compiled kernels: numba compiles each one at its first call, one
after another, before the first step can finish (solver.core._cache keeps them for later
processes). The kernels a scene calls from Python do not depend on one another at that
level, so they can be compiled in parallel: ``warm_kernels(jobs)`` splits the kernels of
the manifest into `jobs` groups of about equal compile time and compiles each group in its
own process into the shared cache; the next process to call a kernel loads it from there.

The manifest (kernel_signatures.json beside this file) lists each kernel that the
default scene calls from Python (module, function, argument types as numba types them,
and its compile time where it was recorded), and the names of the helper functions that
those kernels call (compiled into them, never called from Python).
``python -m solver.app.warm --record`` writes it again from a run of the default scene
(with the jaw moving, lip and teeth contact) in a process with an empty cache;
tests/test_warm.py checks that it still lists what that run calls.

numba's cache files one function's compiled versions under one index, and two processes
that add different versions of the same function at once could each overwrite the
other's. Every function here has one version (its manifest entry), and its versions all go
to the same group; the recording fails where a helper would get two.
"""

import argparse
import ast
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

MANIFEST = Path(__file__).with_name("kernel_signatures.json")
PREFIXES = ("solver.core.kernels.", "solver.rom.")


# ------------------------------------------------------------------ numba types as text

def encode(t):
    """A numba type of a kernel argument as text: 'float64', 'bool', 'float64[2C]'
    (array: dtype, ndim, layout; a trailing 'r' when read-only), 'omitted:<default>'."""
    from numba.core import types
    if isinstance(t, types.Array):
        return f"{t.dtype}[{t.ndim}{t.layout}{'r' if not t.mutable else ''}]"
    if isinstance(t, types.Omitted):
        return f"omitted:{t.value!r}"
    if isinstance(t, (types.Integer, types.Float, types.Boolean, types.NoneType)) \
            and not isinstance(t, types.Literal):
        return str(t)
    raise ValueError(f"no text form for numba type {t!r} (a literal argument compiles "
                     "one version per value: pass a variable)")


def decode(text):
    """The numba type of encode's text."""
    from numba.core import types
    if text.startswith("omitted:"):
        return types.Omitted(ast.literal_eval(text[len("omitted:"):]))
    if text.endswith("]"):
        dtype, _, rest = text[:-1].partition("[")
        readonly = rest.endswith("r")
        rest = rest.rstrip("r")
        return types.Array(decode(dtype), int(rest[:-1]), rest[-1], readonly=readonly)
    if text == "bool":
        return types.boolean
    if text == "none":
        return types.none
    t = getattr(types, text, None)
    if not isinstance(t, types.Type):
        raise ValueError(f"unknown numba type {text!r}")
    return t


# ---------------------------------------------------------------- compiling a group

def _dispatcher(module, name):
    import importlib
    return getattr(importlib.import_module(module), name)


def _compile_group(entries, cache_dir=None):
    """Compile (or load from the cache) each entry's kernel into cache_dir (default: the
    one solver.core._cache picks); runs in a worker process. Returns the seconds it took."""
    from solver.core.numba_config import configure_numba
    configure_numba()
    from solver.core import _cache
    if cache_dir is not None:           # before the kernel modules make their locators
        _cache.CACHE_DIR = Path(cache_dir)
    t0 = time.perf_counter()
    for e in entries:
        _dispatcher(e["module"], e["name"]).compile(tuple(decode(a) for a in e["args"]))
    return time.perf_counter() - t0


def groups(entries, jobs):
    """entries split into at most `jobs` lists of about equal recorded compile time
    (largest first into the lightest group), each function's entries in one group."""
    by_fn = {}
    for e in entries:
        by_fn.setdefault((e["module"], e["name"]), []).append(e)
    bins = [[0.0, []] for _ in range(max(1, int(jobs)))]
    for items in sorted(by_fn.values(), key=lambda v: -sum(e.get("seconds", 1.0) for e in v)):
        lightest = min(bins, key=lambda b: b[0])
        lightest[0] += sum(e.get("seconds", 1.0) for e in items)
        lightest[1].extend(items)
    return [b[1] for b in bins if b[1]]


def load_manifest(path=MANIFEST):
    return json.loads(Path(path).read_text())


def warm_kernels(jobs=None, log=None, manifest=None):
    """Compile the manifest's kernels into the kernel cache in `jobs` processes at once
    (default: the CPUs this process may use), unless solver.core._cache.kernels_warm()
    says this cache holds them already. log: a callable for one line of progress.
    Returns {"warm": already warm, "jobs": processes used, "seconds": wall time}, and
    "error" where a group failed (a stale manifest, a dead process): the kernels then
    compile at their first calls, as without this call."""
    from solver.core.numba_config import configure_numba
    configure_numba()                   # before numba's import: the kernels' flags
    from solver.core._cache import CACHE_DIR, kernels_warm, mark_kernels_warm
    if CACHE_DIR is None or (manifest is None and kernels_warm()):
        return {"warm": CACHE_DIR is not None, "jobs": 0, "seconds": 0.0}
    data = manifest or load_manifest()
    if jobs is None:
        jobs = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
            else (os.cpu_count() or 1)
    parts = groups(data["kernels"], jobs)
    if log:
        log(f"compiling the solver's numba kernels into {CACHE_DIR} in {len(parts)} "
            f"process{'es' if len(parts) > 1 else ''} (first run of these kernels here; "
            "later runs load them)")
    t0 = time.perf_counter()
    try:
        if len(parts) == 1:
            _compile_group(parts[0])
        else:
            with ProcessPoolExecutor(len(parts), mp_context=get_context("spawn")) as pool:
                list(pool.map(_compile_group, parts, [str(CACHE_DIR)] * len(parts)))
    except Exception as exc:            # an optimization: the kernels compile when called
        if log:
            log(f"could not compile the kernels ahead ({type(exc).__name__}: {exc}); they "
                "compile at their first calls")
        return {"warm": False, "jobs": len(parts), "seconds": time.perf_counter() - t0,
                "error": f"{type(exc).__name__}: {exc}"}
    seconds = time.perf_counter() - t0
    if manifest is None:
        mark_kernels_warm()
    if log:
        log(f"compiled the kernels in {seconds:.1f} s")
    return {"warm": False, "jobs": len(parts), "seconds": seconds}


def warm_in_subprocess(log=None):
    """warm_kernels in a child Python process, for a host that must not start workers of
    its own: an FMU's importer, where multiprocessing's spawn would run the host's main
    script again in each worker. The child runs `python -m solver.app.warm` with this
    solver package first on its path; its lines go to log. Skipped (False) where
    sys.executable is not a Python interpreter (a host that embeds Python). Returns
    whether the kernels are compiled after it."""
    from solver.core._cache import kernels_warm
    exe = sys.executable
    if not exe or not Path(exe).name.lower().startswith("python"):
        return False
    root = str(Path(__file__).resolve().parents[2])      # the folder holding solver/
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    try:
        done = subprocess.run([exe, "-m", "solver.app.warm", "--quiet"], env=env,
                              capture_output=True, text=True)
    except OSError:
        return False
    for line in (done.stdout + done.stderr).splitlines():
        if log and line.strip():
            log(line)
    return kernels_warm()


# ------------------------------------------------------------------------ recording

def exercise(steps=3, fidelity="fast"):
    """Run what the manifest covers: the default scene (lip and teeth contact, the jaw)
    built at `fidelity` and stepped `steps` times by 5 ms with the speech gesture's
    activations and the jaw opening by 2 degrees per step."""
    from solver.app.simulation import Simulation, resolve_scene
    sim = Simulation("default", fidelity=fidelity)
    gesture = resolve_scene("speech")
    for k in range(1, steps + 1):
        sim.set_activations(gesture.activations(0.005 * k))
        sim.set_jaw(2.0 * k, 0.0)
        st = sim.step(0.005 * k)
        if not st.converged:
            raise RuntimeError(f"step {k} failed: {st.reason}")
    return sim


def used_kernels():
    """{(module, function): [encoded argument lists]} of the solver's numba functions that
    hold compiled versions in this process."""
    import numba
    out = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith(PREFIXES) or mod is None:
            continue
        for fn, obj in vars(mod).items():
            if isinstance(obj, numba.core.registry.CPUDispatcher) \
                    and obj.py_func.__module__ == name and obj.signatures:
                out[(name, fn)] = [[encode(a) for a in sig] for sig in obj.signatures]
    return out


def _record_here():
    """The manifest from exercise() in this process, whose kernel cache must be empty."""
    from numba.core import event
    from solver.core.numba_config import configure_numba
    configure_numba()
    stack, top, helpers = [], {}, {}

    class Listener(event.Listener):
        def on_start(self, ev):
            f = ev.data["dispatcher"].py_func
            stack.append(((f.__module__, f.__name__), ev.data["args"], time.perf_counter()))

        def on_end(self, ev):
            key, args, t0 = stack.pop()
            if not key[0].startswith(PREFIXES):
                return
            if stack:
                helpers.setdefault(key, set()).add(str(args))
            else:
                top.setdefault(key, []).append(([encode(a) for a in args],
                                                time.perf_counter() - t0))

    event.register("numba:compile", Listener())
    exercise()
    twice = {k: v for k, v in helpers.items() if len(v) > 1}
    if twice:
        raise RuntimeError("helpers compiled in more than one version (pass variables, "
                           f"not constants): {sorted(twice)}")
    kernels = [{"module": m, "name": n, "args": args, "seconds": round(sec, 2)}
               for (m, n), versions in sorted(top.items()) for args, sec in versions]
    return {"scene": "default, fidelity fast, jaw moving, lip and teeth contact",
            "kernels": kernels,
            "helpers": sorted(f"{m}.{n}" for m, n in helpers if (m, n) not in top)}


def record(path=MANIFEST):
    """Write the manifest from a fresh process with an empty kernel cache."""
    with tempfile.TemporaryDirectory(prefix="facefmu-record-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        out = subprocess.run([sys.executable, "-c",
                              "import json, solver.app.warm as w; "
                              "print(json.dumps(w._record_here()))"],
                             env=env, check=True, capture_output=True, text=True).stdout
    data = json.loads(out.strip().splitlines()[-1])
    Path(path).write_text(json.dumps(data, indent=1) + "\n")
    return data


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=None, help="processes (default: the CPUs)")
    ap.add_argument("--record", action="store_true",
                    help=f"write {MANIFEST.name} again from a run of the default scene")
    ap.add_argument("--quiet", action="store_true",
                    help="print nothing where the kernels are compiled already")
    args = ap.parse_args(argv)
    if args.record:
        data = record()
        print(f"wrote {MANIFEST}: {len(data['kernels'])} kernels, "
              f"{sum(e['seconds'] for e in data['kernels']):.1f} s of compilation")
        return 0
    res = warm_kernels(args.jobs, log=print)
    if res["warm"] and not args.quiet:
        print("the solver's kernels are compiled already")
    return 0


if __name__ == "__main__":
    sys.exit(main())
