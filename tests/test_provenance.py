"""Generated tables: one row per key, the latest figures only."""

import subprocess

from solver.app.provenance import commit, upsert_row

HEADER = "| case | figure |\n|---|---|"


def test_a_row_replaces_the_row_of_its_key_and_keeps_the_others(tmp_path):
    path = tmp_path / "table.md"
    upsert_row(path, HEADER, "a", "| a | 1 |")
    upsert_row(path, HEADER, "ab", "| ab | 2 |")
    upsert_row(path, HEADER, "a", "| a | 3 |")
    assert path.read_text().splitlines() == ["| case | figure |", "|---|---|",
                                             "| ab | 2 |", "| a | 3 |"]


def test_a_table_with_another_header_starts_afresh(tmp_path):
    path = tmp_path / "table.md"
    path.write_text("| old | header |\n|---|---|\n| a | 1 |\n")
    upsert_row(path, HEADER, "b", "| b | 2 |")
    assert path.read_text() == HEADER + "\n| b | 2 |\n"


def test_the_commit_says_uncommitted_changes_but_for_the_files_ignored(tmp_path):
    def git(*a):
        subprocess.run(["git", *a], cwd=tmp_path, check=True, capture_output=True)
    git("init", "-q")
    (tmp_path / "code.py").write_text("x = 1\n")
    (tmp_path / "table.md").write_text("| a |\n")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "c")
    head = commit(tmp_path)
    assert head and "uncommitted" not in head
    (tmp_path / "table.md").write_text("| b |\n")
    assert commit(tmp_path) == head + " with uncommitted changes"
    assert commit(tmp_path, ignore=[tmp_path / "table.md"]) == head
    (tmp_path / "code.py").write_text("x = 2\n")
    assert commit(tmp_path, ignore=[tmp_path / "table.md"]) == head + " with uncommitted changes"
