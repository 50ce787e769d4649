"""The solver package's layers, read from its source with ast (nothing is imported): the
finite-element core imports nothing outside the core, and the package's imports have no
cycle but the ones listed in CYCLE_BREAKS, each broken by an import inside a function.

An edge a -> b: module a imports module b, relative or absolute, at module level or
inside a function (`from pkg import name` is an import of pkg.name where that is a
module, else of pkg; a package is its __init__.py). The parent packages that Python runs
before a module (solver/__init__.py, which imports the whole API) are not edges.
"""

import ast
from pathlib import Path

import pytest

SOLVER = Path(__file__).resolve().parents[1] / "solver"

# The finite-element core: mesh, material, assembly, the nonlinear and linear solvers,
# time stepping and the generic terms, with their numba kernels. Knows no face.
CORE = {f"solver.{m}" for m in (
    "mesh", "element", "materials", "assembly", "system", "model", "newton", "linsolve",
    "krylov", "transient", "contact_update", "errors", "units", "_cache", "embedding",
    "strain", "terms.base", "terms.elasticity", "terms.inertia", "terms.loads",
    "terms.gravity")} | {"solver.kernels"} | {
    f"solver.kernels.{p.stem}" for p in (SOLVER / "kernels").glob("*.py")
    if p.stem != "__init__"}
# the face-specific modules and packages (a core module importing one fails the test)
FACE = {f"solver.{m}" for m in ("anatomy", "muscles", "face", "jaw", "scene", "fidelity",
                                "simulation", "rom", "stability", "plot", "io")}

# Imports inside a function that close a cycle: (importer, imported) -> why.
CYCLE_BREAKS = {
    ("solver.rom.simulation", "solver.rom.train"):
        "ReducedSimulation(rom_train=True) trains a missing model on demand, and training "
        "calibrates the model's trust threshold with a ReducedSimulation "
        "(solver.rom.train.calibrate imports solver.rom.simulation in the function too)",
}


def _modules():
    """{dotted module name: path} of every module of the package."""
    out = {}
    for path in sorted(SOLVER.rglob("*.py")):
        parts = list(path.relative_to(SOLVER.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name, path):
    """[(imported module, inside a function)] of the package's modules that module `name`
    (at path) imports."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []

    def target(module, names):
        for n in names:
            sub = f"{module}.{n}"
            found.append(sub if sub in MODULES else module)

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import):
                found.extend((a.name, in_function) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    parts = package.split(".")
                    base = parts[:len(parts) - child.level + 1]
                    module = ".".join(base + ([child.module] if child.module else []))
                else:
                    module = child.module
                before = len(found)
                target(module, [a.name for a in child.names])
                found[before:] = [(m, in_function) for m in found[before:]]
            visit(child, in_function or isinstance(
                child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(ast.parse(path.read_text(), str(path)), False)
    return sorted({(m, f) for m, f in found if m in MODULES and m != name})


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _edges(function_level=True, skip=()):
    """{module: set of imported modules}: module-level imports, and with function_level
    those inside functions too, but the (importer, imported) pairs in skip."""
    return {a: {b for b, inside in deps if (function_level or not inside)
                and (a, b) not in skip} for a, deps in GRAPH.items()}


def _cycle(edges):
    """A cycle [m0, m1, ..., m0] of the graph edges, or None."""
    state, stack = {}, []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for n in sorted(edges.get(m, ())):
            if state.get(n) == "open":
                return stack[stack.index(n):] + [n]
            if n not in state:
                found = visit(n)
                if found:
                    return found
        state[m] = "done"
        stack.pop()
        return None

    for m in sorted(edges):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def _in(module, group):
    return any(module == g or module.startswith(g + ".") for g in group)


def test_the_graph_sees_relative_absolute_and_function_level_imports():
    assert ("solver.newton", False) in GRAPH["solver.model"]                # from .newton
    assert ("solver.kernels.scatter", False) in GRAPH["solver.assembly"]    # from .kernels.x
    assert ("solver._cache", False) in GRAPH["solver"]                      # from . import
    assert ("solver.kernels.geometry", True) in GRAPH["solver.element"]     # in a function
    assert ("solver.rom.simulation", True) in GRAPH["solver.entry"]
    assert ("solver.simulation", False) in GRAPH["solver.rom.simulation"]   # from ..x


def test_the_core_names_existing_modules_and_no_face_module():
    assert CORE <= set(MODULES), sorted(CORE - set(MODULES))
    assert not [m for m in CORE if _in(m, FACE)]
    assert all(any(m == f or m.startswith(f + ".") for m in MODULES) for f in FACE)


@pytest.mark.parametrize("module", sorted(CORE))
def test_a_core_module_imports_only_core_modules(module):
    outside = [(m, "in a function" if inside else "module level")
               for m, inside in GRAPH[module] if m not in CORE]
    assert not outside, (f"{module} imports outside the FE core "
                         f"(face-specific: {[m for m, _ in outside if _in(m, FACE)]}): "
                         f"{outside}")


def test_no_cycle_among_module_level_imports():
    assert _cycle(_edges(function_level=False)) is None


def test_no_cycle_with_function_level_imports_but_the_listed_breaks():
    assert _cycle(_edges(skip=CYCLE_BREAKS)) is None


@pytest.mark.parametrize("pair", sorted(CYCLE_BREAKS))
def test_each_listed_break_is_a_function_level_import_that_closes_a_cycle(pair):
    importer, imported = pair
    assert (imported, True) in GRAPH[importer], f"{importer} no longer imports {imported}"
    assert (imported, False) not in GRAPH[importer]
    others = {p for p in CYCLE_BREAKS if p != pair}
    assert _cycle(_edges(skip=others)) is not None, f"{pair} closes no cycle: drop it"
