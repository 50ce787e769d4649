"""Module docstrings stay short: what a module does and why, in at most about 40 lines.

Derivations, proofs and long case discussions belong in docs/method.md, which the
docstrings point to. This test allows some slack over 40 and names every module of
solver/ whose module docstring runs longer.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SOLVER = ROOT / "solver"
MAX_LINES = 45


def _docstring_lines(path):
    """Number of lines of the module docstring of path (0 without one)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    doc = ast.get_docstring(tree, clean=False)
    return len(doc.splitlines()) if doc else 0


def test_module_docstrings_are_short():
    modules = sorted(p for p in SOLVER.rglob("*.py") if "__pycache__" not in p.parts)
    assert modules, f"no modules found under {SOLVER}"
    too_long = [(p.relative_to(ROOT).as_posix(), n) for p in modules
                if (n := _docstring_lines(p)) > MAX_LINES]
    assert not too_long, (
        f"module docstrings over {MAX_LINES} lines (move derivations to docs/method.md): "
        + ", ".join(f"{name} ({n} lines)" for name, n in too_long))
