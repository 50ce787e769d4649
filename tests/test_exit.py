"""Processes that host FaceFMU exit cleanly: the FMU carries the corrected pythonfmu wrapper
(facefmu.wrapper, patches/pythonfmu), and fresh fmpy processes that instantiate, step,
terminate and free it (alone, two instances, beside the motor-control FMU, a failed
initialization beside a good instance; PARDISO on) all exit with status 0.
The whole campaign (100 processes and 30 runs of the main job) is
`python benchmarks/exit_crash.py --fmu mix --runs 100 --main-job 30`."""

import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import ROOT
from facefmu import wrapper


def _binary(fmu):
    with zipfile.ZipFile(fmu) as z:
        names = [n for n in z.namelist() if n.startswith("binaries/linux64/")]
        assert len(names) == 1, names
        return z.read(names[0])


def test_the_fmu_carries_the_corrected_wrapper(fmu):
    # the installed distribution's file: an FMU loaded earlier in this process may have
    # put its own copy of the pythonfmu package (no binaries) first on sys.path
    from importlib.metadata import distribution
    stock = Path(distribution("pythonfmu").locate_file(
        "pythonfmu/resources/binaries/linux64/libpythonfmu-export.so")).read_bytes()
    shipped = _binary(fmu)
    assert shipped != stock
    assert shipped == wrapper.patched_wrapper().read_bytes()


def test_the_patches_apply_strictly(tmp_path):
    src = tmp_path / "a.txt"
    src.write_text("one\ntwo\nthree\n")
    patch = "--- a/a.txt\n+++ b/a.txt\n@@ -1,3 +1,3 @@\n one\n-two\n+TWO\n three\n"
    wrapper.apply_patch(patch, tmp_path)
    assert src.read_text() == "one\nTWO\nthree\n"
    with pytest.raises(ValueError, match="a.txt"):
        wrapper.apply_patch(patch, tmp_path)                 # "two" is gone
    assert src.read_text() == "one\nTWO\nthree\n"


def test_five_fresh_fmpy_processes_exit_cleanly(tmp_path):
    run = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "exit_crash.py"),
                          "--fmu", "mix", "--runs", "5", "--keep", str(tmp_path)],
                         capture_output=True, text=True, timeout=1200)
    print(run.stdout[-1500:])
    assert re.search(r"^\s+exit code\s+0:\s+5\s+clean exit$", run.stdout, re.M), \
        run.stdout[-3000:] + run.stderr[-3000:]
    assert run.returncode == 0
