"""Where a generated figure comes from: the checkout's commit, the date, the machine."""

import datetime
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def commit(root=ROOT):
    """The checkout's short commit, with " with uncommitted changes" where the tracked
    files differ from it ("unknown" outside a git checkout)."""
    def git(*a):
        try:
            return subprocess.run(["git", *a], cwd=root, capture_output=True,
                                  text=True).stdout.strip()
        except OSError:
            return ""
    head = git("rev-parse", "--short", "HEAD") or "unknown"
    return head + (" with uncommitted changes" if git("status", "--porcelain",
                                                     "--untracked-files=no") else "")


def stamp():
    """'at commit C on YYYY-MM-DD, machine (Python x.y.z)' for a generated file."""
    return (f"at commit {commit()} on {datetime.date.today().isoformat()}, "
            f"{platform.machine()} (Python {platform.python_version()})")


def command(script, argv=None):
    """The command line that ran script (a path relative to the repository) with argv
    (default: this process's arguments)."""
    args = sys.argv[1:] if argv is None else argv
    return " ".join(["python", script, *args])
