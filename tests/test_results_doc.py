"""docs/RESULTS.md's generated tables (``python -m benchmarks.results``): the document never
drifts from its saved benchmark JSON, and the marker replacement leaves the prose alone.

Cheap: nothing here runs a benchmark; the check renders the saved JSON in ``docs/results/data``.
"""

from __future__ import annotations

import importlib.util
import json

import pytest

from benchmarks import results
from benchmarks.results import RUNS, ResultsError, begin_marker, end_marker, first_difference, render_doc
from benchmarks.results_tables import SECTIONS, Section, table


def test_results_md_is_what_its_saved_json_renders():
    assert first_difference(results.DOC.read_text(), SECTIONS) is None, \
        "docs/RESULTS.md differs from docs/results/data: run python -m benchmarks.results"


def test_every_section_reads_runs_that_exist_and_have_a_data_file():
    for section in SECTIONS:
        for run in section.runs:
            assert run in RUNS, (section.name, run)
            assert importlib.util.find_spec(f"benchmarks.{RUNS[run][0]}") is not None, RUNS[run]
            saved = json.loads((results.DATA / f"{run}.json").read_text())
            assert saved["command"] == results.command(run)
            assert {"date_utc", "commit", "loadavg_before", "result"} <= set(saved)


def test_check_exits_1_naming_the_section_when_a_number_was_edited_by_hand(tmp_path, monkeypatch, capsys):
    doc = tmp_path / "RESULTS.md"
    text = results.DOC.read_text()
    i = text.index(begin_marker("realdata"))
    j = text.index(end_marker("realdata"))
    body = text[i:j]
    edited = body.replace("|", "| 9.999 |", 1)         # a cell added inside the generated table
    doc.write_text(text[:i] + edited + text[j:])
    monkeypatch.setattr(results, "DOC", doc)
    before = doc.read_text()
    assert results.main(["--check"]) == 1
    out = capsys.readouterr().out
    assert "'realdata'" in out and len(out.strip().splitlines()) == 1
    assert doc.read_text() == before                    # --check writes nothing
    doc.write_text(text)
    assert results.main(["--check"]) == 0


def _demo(tmp_path, rows):
    data = tmp_path / "data"
    data.mkdir()
    (data / "demo_run.json").write_text(json.dumps({"command": "python -m benchmarks.demo", "result": {"rows": rows}}))
    section = Section("demo", ("demo_run",), lambda d: table(["x", "y"], [[str(a), f"{b:.2f}"] for a, b in d["rows"]]))
    return section, data


PROSE_BEFORE = "# Title\n\nSome prose with a number 1.23 that is not generated.\n\n"
PROSE_AFTER = "\n\nMore prose | with a pipe.\n<!-- an ordinary comment -->\n"


def test_replacement_changes_only_the_text_between_the_markers(tmp_path):
    section, data = _demo(tmp_path, [[1, 0.5], [2, 0.25]])
    stale = PROSE_BEFORE + begin_marker("demo") + "\n\n| x | y |\n|---|---|\n| 1 | 0.99 |\n\n" + \
        end_marker("demo") + PROSE_AFTER
    assert first_difference(stale, [section], data) == "demo"
    new = render_doc(stale, [section], data)
    body = "\n\n| x | y |\n|---|---|\n| 1 | 0.50 |\n| 2 | 0.25 |\n\n"
    assert new.startswith(PROSE_BEFORE + begin_marker("demo") + body)
    assert new.endswith(end_marker("demo") + PROSE_AFTER)
    assert "0.99" not in new
    assert render_doc(new, [section], data) == new        # rendering again changes nothing
    assert first_difference(new, [section], data) is None


def test_a_missing_data_file_is_an_error_naming_the_section_and_the_command(tmp_path):
    section, data = _demo(tmp_path, [[1, 0.5]])
    (data / "demo_run.json").unlink()
    text = PROSE_BEFORE + begin_marker("demo") + "\n" + end_marker("demo") + PROSE_AFTER
    with pytest.raises(ResultsError, match=r"section 'demo': no data file demo_run\.json .*--run demo_run"):
        render_doc(text, [section], data)


def test_markers_missing_repeated_or_unknown_are_errors_naming_the_section(tmp_path):
    section, data = _demo(tmp_path, [[1, 0.5]])
    with pytest.raises(ResultsError, match="section 'demo'"):
        render_doc(PROSE_BEFORE, [section], data)
    twice = (begin_marker("demo") + "\n" + end_marker("demo") + "\n") * 2
    with pytest.raises(ResultsError, match="section 'demo'"):
        render_doc(twice, [section], data)
    unknown = begin_marker("demo") + "\n" + end_marker("demo") + "\n" + begin_marker("other") + "\n"
    with pytest.raises(ResultsError, match="section 'other'"):
        render_doc(unknown, [section], data)
