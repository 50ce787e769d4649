"""Generated tables: one row per key, the latest figures only."""

from solver.app.provenance import upsert_row

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
