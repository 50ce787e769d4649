"""numba's process-wide settings are one explicit call (solver.configure_numba), not an
import side effect; every solver module with numba kernels files them in the solver's own
kernel cache (solver.core._cache), whose stamp covers every kernel file."""

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SOLVER = Path(__file__).resolve().parents[1] / "solver"


def _child(code, **env):
    base = {k: v for k, v in os.environ.items()
            if k not in ("NUMBA_THREADING_LAYER", "NUMBA_DISABLE_INTEL_SVML")}
    run = subprocess.run([sys.executable, "-c", code], env={**base, **env},
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_importing_solver_changes_no_numba_setting_and_loads_no_numba():
    res = _child("""
import json, os, sys
import solver
print(json.dumps({"numba": "numba" in sys.modules,
                  "env": {k: v for k, v in os.environ.items() if k.startswith("NUMBA_")},
                  "api": sorted(n for n in solver.__all__ if getattr(solver, n) is None)}))
""")
    assert res == {"numba": False, "env": {}, "api": []}


def test_the_exported_names_resolve_to_the_real_entry_points():
    import solver
    from solver.entry import open_simulation
    from solver.core.model import Model
    assert solver.open_simulation is open_simulation and solver.Model is Model
    assert set(solver.__all__) <= set(dir(solver))
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        solver.nothing


def test_configure_numba_sets_the_workqueue_layer_and_no_svml_for_the_kernels():
    res = _child("""
import json, os
import numpy as np
import solver
before = {k: os.environ.get(k) for k in ("NUMBA_THREADING_LAYER", "NUMBA_DISABLE_INTEL_SVML")}
told = solver.configure_numba()
from solver.core.mesh import Mesh
from solver.core.model import Model
from solver.core.materials import MooneyRivlin
import numba
X = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
m = Model(Mesh(X, np.array([[0, 1, 3, 2, 4, 5, 7, 6]])), MooneyRivlin(c10=2.5e-3, d=0.8))
m.fix([0, 1, 2, 3]); m.prescribe([4, 5], displacement=(0, 0, 0.1))
res = m.solve_static()
print(json.dumps({"before": before, "told": told, "layer": numba.threading_layer(),
                  "svml": numba.config.USING_SVML, "converged": bool(res.converged)}))
""")
    assert res["before"] == {"NUMBA_THREADING_LAYER": None, "NUMBA_DISABLE_INTEL_SVML": None}
    assert res["told"] == {"threading_layer": "workqueue", "svml": None}
    assert res["converged"] and res["layer"] == "workqueue" and res["svml"] is False


def test_a_threading_layer_the_user_chose_is_kept():
    res = _child("""
import json, solver, numba
told = solver.configure_numba()
print(json.dumps({"told": told, "config": numba.config.THREADING_LAYER}))
""", NUMBA_THREADING_LAYER="safe")
    assert res == {"told": {"threading_layer": "safe", "svml": False}, "config": "safe"}


_TOO_LATE = """
import json, sys, warnings
for name in {hidden!r}:                 # a layer this environment cannot load
    sys.modules[f"numba.np.ufunc.{{name}}pool"] = None
import numba
@numba.njit(parallel=True)
def total(n):
    s = 0
    for i in numba.prange(n):
        s += i
    return s
# a layer other than configure_numba's, whichever of them loads here: 'forksafe' would
# fall back to workqueue where TBB's library is off the loader's path (a venv's pip tbb)
for layer in ("tbb", "omp"):
    numba.config.THREADING_LAYER = layer
    try:
        total(10)
        break
    except ValueError:
        pass
else:
    print(json.dumps({{"layer": None}}))
    raise SystemExit(0)
import solver
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    solver.configure_numba()
print(json.dumps({{"layer": numba.threading_layer(),
                  "warnings": [str(w.message) for w in caught]}}))
"""


def _too_late(hidden=()):
    """Launch TBB or OpenMP (the first that loads, the hidden ones left out), then call
    configure_numba; returns {"layer": the running layer or None, "warnings": [...]}."""
    return _child(_TOO_LATE.format(hidden=tuple(hidden)))


@pytest.mark.parametrize("hidden", [(), ("tbb",)], ids=["any", "without-tbb"])
def test_configure_numba_too_late_warns_naming_the_running_layer(hidden):
    res = _too_late(hidden)
    if res["layer"] is None:
        pytest.skip("neither numba's TBB nor its OpenMP layer loads in this environment")
    assert res["layer"] in ("tbb", "omp")
    assert any(repr(res["layer"]) in w and "configure_numba() before" in w
               for w in res["warnings"]), res


def test_with_no_layer_to_launch_the_warning_test_has_nothing_to_check():
    assert _too_late(("tbb", "omp")) == {"layer": None}


def _module_imports(path):
    """Names of the modules imported at module level by the file at path."""
    names = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names}
    return names


def kernel_files_outside_the_cache(root=SOLVER):
    """Files with numba kernels that can be imported before solver.core._cache (the solver's
    kernel cache, with a stamp over every kernel file): a module-level import of
    solver.core._cache or of a module of solver.core.kernels (whose package imports it)."""
    bad = []
    for path in sorted(root.rglob("*.py")):
        if "@njit" not in path.read_text() or path.name == "_cache.py":
            continue
        if root / "core" / "kernels" in path.parents:     # its package imports the cache
            continue
        imports = _module_imports(path)
        if not any(n == "solver.core._cache" or n.startswith("solver.core.kernels")
                   for n in imports):
            bad.append(path.relative_to(root).as_posix())
    return bad


def test_every_kernel_file_imports_the_solver_kernel_cache_first():
    assert kernel_files_outside_the_cache() == []


def test_the_rule_catches_a_kernel_file_without_the_cache(tmp_path):
    (tmp_path / "rom").mkdir()
    (tmp_path / "rom" / "k.py").write_text("from numba import njit\n\n@njit(cache=True)\n"
                                           "def f(x):\n    return x\n")
    assert kernel_files_outside_the_cache(tmp_path) == ["rom/k.py"]


def test_the_cache_tells_a_first_run_until_a_step_has_compiled_its_kernels(tmp_path,
                                                                          monkeypatch):
    """kernels_warm() is False in an empty cache and for other kernel sources, True once a
    step has marked it; the notice names the cache."""
    from solver.core import _cache
    monkeypatch.setattr(_cache, "CACHE_DIR", tmp_path)
    assert not _cache.kernels_warm()
    assert str(tmp_path) in _cache.compile_notice()
    _cache.mark_kernels_warm()
    assert _cache.kernels_warm()
    root = Path(_cache.__file__).resolve().parents[1]
    monkeypatch.setitem(_cache._KERNEL_STAMP, root, "0" * 64)        # edited kernels
    assert not _cache.kernels_warm()
    monkeypatch.setattr(_cache, "CACHE_DIR", None)                 # no cache at all
    assert not _cache.kernels_warm()
    _cache.mark_kernels_warm()
