"""Before and after in one call: run a benchmark of this checkout on another commit's code.

    with checkout("HEAD~1") as code:                 # a detached git worktree of it
        before = run_json("benchmarks/step_cost.py", ["--fidelity", "fast"], code)
    after = run_json("benchmarks/step_cost.py", ["--fidelity", "fast"])

run_json runs the script (this checkout's) in a fresh process with `--json FILE` added,
importing the packages from `code` (a folder holding solver/ and facefmu/; default this
checkout), and returns what the script wrote to FILE. The solver's numba kernels are
cached by module and source content (solver.core._cache): where the two commits' kernel
sources differ, each run compiles its own.
"""

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _git(*args):
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True,
                          text=True).stdout.strip()


def describe(rev):
    """The short commit of rev in this checkout (ValueError where git does not know it)."""
    try:
        return _git("rev-parse", "--short", f"{rev}^{{commit}}")
    except subprocess.CalledProcessError as exc:
        raise ValueError(f"--before {rev!r}: not a commit of this checkout") from exc


@contextlib.contextmanager
def checkout(rev):
    """A temporary detached worktree of rev (its folder), removed on exit."""
    describe(rev)
    folder = Path(tempfile.mkdtemp(prefix="facefmu-before-")) / "tree"
    _git("worktree", "add", "--detach", str(folder), rev)
    try:
        yield folder
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(folder)], cwd=ROOT,
                       capture_output=True)
        shutil.rmtree(folder.parent, ignore_errors=True)


def run_json(script, argv, code=None):
    """Run script (relative to ROOT, or absolute) with argv and --json in a fresh process
    on the code at `code`; the JSON it wrote. Its output goes to this process's; a
    failure raises RuntimeError."""
    code = Path(code or ROOT)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [str(code)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
        done = subprocess.run([sys.executable, str(ROOT / script), *argv, "--json", str(out)],
                              env=env, cwd=code)
        if done.returncode != 0 or not out.is_file():
            raise RuntimeError(f"{script} on {code} failed (status {done.returncode})")
        return json.loads(out.read_text())
