"""The README's Python examples run as written."""

import re

from conftest import ROOT


def test_readme_python_examples_run(capsys):
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert blocks
    for block in blocks:
        exec(compile(block, "README.md", "exec"), {})
    assert "protrusion" in capsys.readouterr().out
