"""The fault matrix for docs/RESULTS.md: runs the matrix rows (tests/test_faults_*.py, one test
per row) and prints a markdown table of each row's expected behaviour (the test's
docstring), what it measured (``record_property("measured", ...)``) and its result.

Prints the table on stdout, then JSON as its last line: ``rows`` (name, file, expected,
measured, result, seconds), ``passed``, ``failed``, ``seconds``. pytest's own report goes to
stderr. Extra arguments go to pytest (e.g. ``-m "not pty"`` or ``-k csv``).
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks._common import emit  # noqa: E402

GROUPS = {"serial": "serial link", "can": "CAN bus", "live": "live link (pty)", "files": "bad input",
          "soak": "all at once"}


def _one_line(text: str | None) -> str:
    return " ".join((text or "").split())


class MatrixCollector:
    """pytest plugin: one row per test function (parametrized cases merged)."""

    def __init__(self) -> None:
        self.rows: dict[str, dict] = {}

    def _row(self, nodeid: str) -> dict:
        path, _, name = nodeid.partition("::")
        func = name.split("[")[0]
        return self.rows.setdefault(f"{path}::{func}", {
            "row": func.removeprefix("test_").replace("_", " "),
            "group": GROUPS.get(Path(path).stem.removeprefix("test_faults_"), Path(path).stem),
            "expected": "", "measured": [], "result": "passed", "seconds": 0.0})

    @pytest.hookimpl
    def pytest_collection_modifyitems(self, items: list) -> None:
        for item in items:
            self._row(item.nodeid)["expected"] = _one_line(getattr(item.function, "__doc__", ""))

    @pytest.hookimpl
    def pytest_runtest_logreport(self, report) -> None:
        row = self._row(report.nodeid)
        row["seconds"] += report.duration
        if report.failed:
            row["result"] = "FAILED"
        if report.when == "call":
            case = report.nodeid.partition("[")[2].rstrip("]")
            for key, value in report.user_properties:
                if key == "measured":
                    row["measured"].append(f"{case}: {value}" if case else str(value))


def table(rows: list[dict]) -> str:
    lines = ["| # | fault | row | expected behaviour | measured | result |", "|---|---|---|---|---|---|"]
    for i, r in enumerate(rows, 1):
        measured = "<br>".join(m.replace("|", "\\|") for m in r["measured"]) or "—"
        lines.append(f"| {i} | {r['group']} | {r['row']} | {r['expected'].replace('|', '/')} | {measured} | "
                     f"{r['result']} |")
    return "\n".join(lines)


def main() -> int:
    files = sorted(str(p.relative_to(REPO)) for p in (REPO / "tests").glob("test_faults_*.py")
                   if p.name != "test_faults_support.py")
    collector = MatrixCollector()
    os.chdir(REPO)
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(sys.stderr):
        code = pytest.main(["-q", "-p", "no:cacheprovider", *files, *sys.argv[1:]], plugins=[collector])
    seconds = time.perf_counter() - t0
    order = list(GROUPS.values())
    rows = sorted(collector.rows.values(), key=lambda r: order.index(r["group"]) if r["group"] in order else len(order))
    print(table(rows))
    print()
    failed = sum(r["result"] != "passed" for r in rows)
    emit({"rows": rows, "passed": len(rows) - failed, "failed": failed, "seconds": round(seconds, 1)})
    return 0 if code == 0 and not failed else 1


if __name__ == "__main__":
    sys.exit(main())
