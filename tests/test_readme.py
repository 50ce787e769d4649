"""The README's Python examples run as written.

Every ```python block of README.md runs in a fresh namespace, one test per block (its id
is the line of the fence); ```bash blocks are not run.
"""

import re

import pytest

from conftest import ROOT

README = ROOT / "README.md"


def python_blocks(text):
    """(line of the opening fence, code) for every ```python block of a Markdown text."""
    return [(text.count("\n", 0, m.start()) + 1, m.group(1))
            for m in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M)]


BLOCKS = python_blocks(README.read_text())


def test_readme_has_python_examples():
    assert BLOCKS


@pytest.mark.parametrize("line, code", BLOCKS, ids=[f"README.md:{line}" for line, _ in BLOCKS])
def test_readme_python_example_runs(line, code, capsys):
    exec(compile("\n" * line + code, str(README), "exec"), {"__name__": "__main__"})
    if "print(" in code:
        assert capsys.readouterr().out.strip()
