"""scripts/readme_tables.py: the README's accuracy and speed tables are what their committed JSON says."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


@pytest.fixture(scope="module")
def tables(script):
    return script("readme_tables")


def test_the_readme_tables_match_their_json(tables):
    text = README.read_text()
    assert tables.update(text) == text, "stale README tables: run .venv/bin/python scripts/readme_tables.py"


def test_every_row_names_a_committed_file_and_the_command_that_wrote_it(tables):
    for table in tables.TABLES:
        for row in table.rows:
            assert (ROOT / "docs" / "results" / row.file).is_file(), row.file
            assert f"--json docs/results/{row.file}" in row.command, (row.label, row.command)


def test_a_changed_figure_changes_the_table(tables, tmp_path):
    """Regenerating against a result that moved gives another README: the check can fail."""
    results = tmp_path / "results"
    shutil.copytree(ROOT / "docs" / "results", results)
    text = README.read_text()
    rgb = json.loads((results / "test-rgb.json").read_text())
    assert f"| {100 * rgb['methods']['ours']['k1']['20']:.1f} |" in text
    rgb["methods"]["ours"]["k1"]["20"] = 0.123
    (results / "test-rgb.json").write_text(json.dumps(rgb))
    new = tables.update(text, results=results)
    assert new != text and "| 12.3 |" in new
    bench = json.loads((results / tables.BENCH).read_text())
    bench["targets"]["roll_http_frame_p50_ms"]["met"] = True
    (results / tables.BENCH).write_text(json.dumps(bench))
    assert tables.update(text, results=results).count("| met |") == text.count("| met |") + 1


def test_a_missing_key_or_marker_is_one_clear_error(tables, tmp_path):
    row = tables.Row("x", "test-rgb.json", "cmd", {"method": "nobody"})
    broken = tables.Table("accuracy", tables.ACCURACY.columns, (row,))
    with pytest.raises(tables.TableError, match="test-rgb.json: no 'methods.nobody.k1.180'"):
        tables.render(broken)
    with pytest.raises(tables.TableError, match="want one <!-- table:accuracy -->"):
        tables.update("no markers here")


def test_the_command_line_check(tables, tmp_path, monkeypatch, capsys):
    readme = tmp_path / "README.md"
    readme.write_text(README.read_text().replace("| **missed** |", "| met |", 1))
    monkeypatch.setattr(sys, "argv", ["readme_tables.py", "--check", "--readme", str(readme)])
    with pytest.raises(SystemExit, match="tables differ"):
        tables.main()
    monkeypatch.setattr(sys, "argv", ["readme_tables.py", "--readme", str(readme)])
    tables.main()
    assert readme.read_text() == README.read_text()
