"""Where a generated figure comes from: the checkout's commit, the date, the machine."""

import datetime
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def commit(root=ROOT, ignore=()):
    """The checkout's short commit, with " with uncommitted changes" where the tracked
    files differ from it ("unknown" outside a git checkout); the files ignore (paths) do
    not count (a table that earlier calls of the same command have been writing)."""
    def git(*a):
        try:
            return subprocess.run(["git", *a], cwd=root, capture_output=True,
                                  text=True).stdout.strip()
        except OSError:
            return ""
    head = git("rev-parse", "--short", "HEAD") or "unknown"
    skip = [f":(exclude){Path(p).resolve()}" for p in ignore]
    return head + (" with uncommitted changes" if git("status", "--porcelain",
                                                     "--untracked-files=no", "--", ".",
                                                     *skip) else "")


def stamp():
    """'at commit C on YYYY-MM-DD, machine (Python x.y.z)' for a generated file."""
    return (f"at commit {commit()} on {datetime.date.today().isoformat()}, "
            f"{platform.machine()} (Python {platform.python_version()})")


def command(script, argv=None):
    """The command line that ran script (a path relative to the repository) with argv
    (default: this process's arguments)."""
    args = sys.argv[1:] if argv is None else argv
    return " ".join(["python", script, *args])


def upsert_row(path, header, key, row):
    """Write the markdown table row `row` (a line starting "| key ") into the table file
    path, replacing the row of the same key: a table that benchmarks fill one row per call
    holds each key's latest figures only. header: the table's first two lines; a new file,
    or one whose header differs, starts afresh."""
    path = Path(path)
    lines = path.read_text().splitlines() if path.is_file() else []
    head = header.rstrip("\n").splitlines()
    if lines[:len(head)] != head:
        lines = head
    prefix = f"| {key} "
    body = [ln for ln in lines[len(head):] if ln.strip() and not ln.startswith(prefix)]
    path.write_text("\n".join(head + body + [row.rstrip("\n")]) + "\n")
