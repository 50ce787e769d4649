"""The solver package's layers, read from its source with ast (nothing is imported): the
finite-element core imports nothing outside the core, and the package's imports have no
cycle, at module level or inside functions.

An edge a -> b: module a imports module b, relative or absolute, at module level or
inside a function (`from pkg import name` is an import of pkg.name where that is a
module, else of pkg; a package is its __init__.py). The parent packages that Python runs
before a module (solver/__init__.py, which exports the API lazily) are not edges.
"""

import ast
from pathlib import Path

import pytest

SOLVER = Path(__file__).resolve().parents[1] / "solver"

# The layers, bottom up: a module may import modules of its own layer and of the layers
# below it, never above. The core (mesh, element, materials, assembly, Newton, linear
# solvers, time stepping, generic terms, numba kernels) knows no face; the face
# (anatomies, muscles, stiffening, cables, contact, jaw, lip measures) knows no
# application; the application (scenes, fidelities, Simulation, export, plots) knows no
# reduced model; the reduced model (solver.rom) builds on the application's Simulation;
# the runners (the factory solver.entry.open_simulation, above the full and the reduced
# simulation, and the parallel sweeps that use it); validation (the stability cases,
# Table 4) uses all of them; the package's __init__ exports from every layer.
LAYERS = (("solver.core",), ("solver.face",), ("solver.app",), ("solver.rom",),
          ("solver.entry", "solver.sweep"), ("solver.validation",), ("solver",))


def layer(module):
    """The index of module's layer in LAYERS."""
    for i, group in enumerate(LAYERS):
        if any(module == g or module.startswith(g + ".") for g in group if g != "solver"):
            return i
    assert module == "solver", f"{module} is in no layer"
    return len(LAYERS) - 1


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


def _edges(function_level=True):
    """{module: set of imported modules}: module-level imports, and with function_level
    those inside functions too."""
    return {a: {b for b, inside in deps if function_level or not inside}
            for a, deps in GRAPH.items()}


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


def test_the_graph_sees_relative_absolute_and_function_level_imports():
    assert ("solver.core.newton", False) in GRAPH["solver.core.model"]
    assert ("solver.core.kernels.scatter", False) in GRAPH["solver.core.assembly"]
    assert ("solver.core.numba_config", False) in GRAPH["solver"]            # from x import m
    assert ("solver.core.kernels.geometry", True) in GRAPH["solver.core.element"]  # in a function
    assert ("solver.rom.simulation", True) in GRAPH["solver.entry"]
    assert ("solver.app.simulation", False) in GRAPH["solver.rom.simulation"]


def test_every_module_is_in_a_layer_and_every_layer_has_modules():
    assert all(layer(m) is not None for m in MODULES)
    assert all(any(layer(m) == i for m in MODULES) for i in range(len(LAYERS)))


@pytest.mark.parametrize("module", sorted(MODULES))
def test_a_module_imports_nothing_from_a_layer_above_its_own(module):
    above = [(m, "in a function" if inside else "module level")
             for m, inside in GRAPH[module] if layer(m) > layer(module)]
    assert not above, f"{module} ({LAYERS[layer(module)]}) imports from above: {above}"


def test_the_layer_rule_catches_a_core_module_that_imports_the_face():
    module = "solver.core.model"
    graph = dict(GRAPH)
    graph[module] = GRAPH[module] + [("solver.face.face_model", True)]
    assert [m for m, _ in graph[module] if layer(m) > layer(module)] == ["solver.face.face_model"]


def test_no_cycle_among_module_level_imports():
    assert _cycle(_edges(function_level=False)) is None


def test_no_cycle_with_function_level_imports():
    assert _cycle(_edges()) is None
