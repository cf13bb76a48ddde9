"""testkit.shared: a result built once per run and per key, whole or not at all, by one process
at a time (the other processes of the run wait for it and read it)."""

from __future__ import annotations

import multiprocessing
import time
from pathlib import Path

import pytest

from testkit import shared


@pytest.fixture
def root(tmp_path, monkeypatch):
    monkeypatch.setattr(shared, "_root", None)
    shared.set_root(tmp_path / "shared")
    return tmp_path / "shared"


def _count_build(log: Path):
    def build(out: Path) -> None:
        with open(log, "a") as f:
            f.write("built\n")
        (out / "value.txt").write_text("42")
    return build


def test_a_result_is_built_once_per_key_and_read_back(root, tmp_path):
    log = tmp_path / "log"
    a = shared.shared_dir("thing", (1, "x"), _count_build(log))
    b = shared.shared_dir("thing", (1, "x"), _count_build(log))
    c = shared.shared_dir("thing", (2, "x"), _count_build(log))
    assert a == b != c and a.parent == root
    assert (a / "value.txt").read_text() == "42" and (c / "value.txt").read_text() == "42"
    assert log.read_text().count("built") == 2


def test_the_key_holds_the_source_digest(root, tmp_path, monkeypatch):
    log = tmp_path / "log"
    a = shared.shared_dir("thing", (1,), _count_build(log))
    monkeypatch.setattr(shared, "source_digest", lambda: "another state of the code")
    assert shared.shared_dir("thing", (1,), _count_build(log)) != a
    assert log.read_text().count("built") == 2


def test_a_build_that_fails_leaves_nothing_and_the_next_caller_builds(root, tmp_path):
    def failing(out: Path) -> None:
        (out / "half.txt").write_text("half")
        raise RuntimeError("stopped")

    with pytest.raises(RuntimeError, match="stopped"):
        shared.shared_dir("thing", (1,), failing)
    assert sorted(p.name for p in root.iterdir() if not p.name.endswith(".lock")) == []
    out = shared.shared_dir("thing", (1,), _count_build(tmp_path / "log"))
    assert (out / "value.txt").read_text() == "42" and not (out / "half.txt").exists()


def _slow_build_in_another_process(root: str, log: str) -> None:
    shared.set_root(Path(root))

    def build(out: Path) -> None:
        with open(log, "a") as f:
            f.write("built\n")
        time.sleep(1.0)
        (out / "value.txt").write_text("slow")

    shared.shared_dir("thing", (1,), build)


def test_a_second_process_waits_for_the_first_and_reads_its_result(root, tmp_path):
    log = tmp_path / "log"
    ctx = multiprocessing.get_context("fork")
    other = ctx.Process(target=_slow_build_in_another_process, args=(str(root), str(log)))
    other.start()
    deadline = time.monotonic() + 10.0
    while not log.exists() and time.monotonic() < deadline:       # the other process holds the lock
        time.sleep(0.01)
    out = shared.shared_dir("thing", (1,), _count_build(log))
    other.join(10.0)
    assert other.exitcode == 0
    assert (out / "value.txt").read_text() == "slow"
    assert log.read_text().count("built") == 1


def test_identified_keys_by_the_bytes_of_its_input_files(root, tmp_path, monkeypatch):
    """The same arguments on a changed file are another result (no identification runs here: the
    command is replaced by one that writes what it was given)."""
    import rtlift.app.cli as cli

    calls = []

    def fake_main(argv):
        calls.append(argv)
        Path(argv[argv.index("-o") + 1]).write_text(Path(argv[2]).read_text())
        return 0

    monkeypatch.setattr(cli, "main", fake_main)
    rec = tmp_path / "static.csv"
    rec.write_text("one")
    first = shared.identified("--static", rec)
    assert shared.identified("--static", rec) == first and len(calls) == 1
    rec.write_text("two")
    second = shared.identified("--static", rec)
    assert second != first and len(calls) == 2
    assert first.read_text() == "one" and second.read_text() == "two"
