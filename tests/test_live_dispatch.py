"""The observer loop's one per-sample dispatch (rtlift.app.live, issue 50): every listener given at
construction sees every estimate — received, gap-filled or bridged across a reconnect — with the
same row, in the order given, and the estimates file is one of them."""

from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path
from types import SimpleNamespace

import pytest

from rtlift.app.live import FLAG_LINK_GAP, MAX_FILL, EstimateWriter, ObserverLoop
from rtlift.model.modelfile import load_model
from rtlift.observer import Observer

MODEL = Path(__file__).parent / "data" / "bench_model.json"
SEQS = (0, 1, 2, 5, 6, 7)
"""Six samples received, two missing (3, 4), then a reconnect gap of 5 (bridged) and two more."""


class Recorder:
    """A listener keeping a copy of each row (the estimate's fields copied: the object is reused)."""

    def __init__(self, log: list, name: str) -> None:
        self.rows: list[tuple] = []
        self.stopped = 0
        self.log, self.name = log, name

    def on_sample(self, index, t, seq, t_us, cmu, env, dcl, est) -> None:
        self.rows.append((index, t, seq, t_us, cmu, env, dcl, est.dcl, est.model_dcl, est.innovation, est.flags))
        self.log.append(self.name)

    def on_stop(self) -> None:
        self.stopped += 1


class Swapper:
    """A stand-in for ``--adapt``'s adapter: records what the loop tells it."""

    busy = False

    def __init__(self, log: list) -> None:
        self.loop = None
        self.before: list[tuple[int, float]] = []
        self.after: list[tuple] = []
        self.log = log

    def before_step(self, index: int, cmu: float) -> None:
        self.before.append((index, cmu))

    def after_step(self, index: int, cmu: float, env: float, dcl: float | None) -> None:
        self.after.append((index, cmu, env, dcl))
        self.log.append("adapter")


class Monitor:
    def __init__(self, log: list) -> None:
        self.calls: list[tuple] = []
        self.log = log

    def step(self, dcl, model_dcl, innovation, envelope) -> None:
        self.calls.append((dcl, model_dcl, innovation, envelope))
        self.log.append("monitor")


def _converter(sample):
    k = sample.seq
    return 0.001 * (k % 3), 0.002, None if k == 6 else 0.01 * k


def _sample(seq: int) -> SimpleNamespace:
    return SimpleNamespace(seq=seq, t_us=seq * 2500, host_time=time.perf_counter())


@pytest.fixture()
def run(tmp_path):
    log: list[str] = []
    first, last = Recorder(log, "first"), Recorder(log, "last")
    monitor, swapper, tap = Monitor(log), Swapper(log), deque(maxlen=100)
    writer = EstimateWriter(tmp_path / "e.csv")
    loop = ObserverLoop(Observer.from_model(load_model(MODEL)), _converter, 1 << 16, monitor=monitor,
                        adapter=swapper, tap=tap, writer=writer, listeners=[first, last])
    for seq in SEQS:
        loop.feed(_sample(seq))
    loop.bridge(5, known=True)
    for seq in (20, 21):
        loop.feed(_sample(seq))
    loop.stop()
    return SimpleNamespace(loop=loop, log=log, first=first, last=last, monitor=monitor, swapper=swapper, tap=tap,
                           csv=tmp_path / "e.csv")


def test_every_listener_sees_every_estimate_in_the_order_given(run):
    loop, rows = run.loop, run.first.rows
    assert (loop.stats.samples, loop.stats.filled, loop.stats.bridged) == (8, 2, 5)
    assert loop.stats.estimates == len(rows) == 15
    assert run.last.rows == rows and run.first.stopped == run.last.stopped == 1
    assert [r[0] for r in rows] == list(range(15))       # 0-7 received and filled, 8-12 bridged, 13-14
    assert run.log == ["monitor", "adapter", "first", "last"] * 15
    assert run.loop.adapter is run.swapper and run.swapper.loop is run.loop


def test_the_rows_say_what_kind_of_step_made_them(run):
    rows = {r[0]: r for r in run.first.rows}
    index, t, seq, t_us, cmu, env, dcl, *_, flags = rows[3]                 # filled: seq 3 missing
    assert (seq, t_us, dcl, cmu, env) == (3, None, None, 0.001 * (2 % 3), 0.002)
    assert t == pytest.approx(3 / 400.0, abs=0, rel=1e-15)
    assert not flags & FLAG_LINK_GAP
    for i in range(8, 13):                                                   # bridged: seq known
        assert rows[i][2] == i and rows[i][3] is None and rows[i][6] is None
        assert rows[i][-1] & FLAG_LINK_GAP
    assert rows[13][2] == 20 and rows[13][3] == 20 * 2500 and rows[13][6] == pytest.approx(0.2)
    assert rows[6][6] is None and rows[5][6] == pytest.approx(0.05)         # seq 6 flagged by the converter


def test_the_monitor_the_adapter_and_the_tap_get_their_parts_of_the_row(run):
    rows = run.first.rows
    assert run.monitor.calls == [(r[6], r[8], r[9], r[5]) for r in rows]
    assert run.swapper.after == [(r[0], r[4], r[5], r[6]) for r in rows]    # bridged rows too
    assert [i for i, _ in run.swapper.before] == [0, 1, 2, 5, 6, 7, 13, 14]  # received samples only
    tap = list(run.tap)
    assert len(tap) == 15
    for (index, dcl, est, model, nu, _nis), r in zip(tap, rows, strict=True):
        assert (index, dcl, est, model) == (r[0], r[6], r[7], r[8])
        assert nu == r[9] or (math.isnan(nu) and math.isnan(r[9]))


def test_the_estimates_file_is_the_rows_bit_for_bit(run):
    lines = [x for x in run.csv.read_text().splitlines() if x and not x.startswith("#")][1:]
    assert len(lines) == 15
    for line, r in zip(lines, run.first.rows, strict=True):
        cells = line.split(",")
        assert int(cells[0]) == r[0] and float(cells[1]) == r[1]
        assert cells[2] == ("" if r[2] is None else str(r[2])) and cells[3] == ("" if r[3] is None else str(r[3]))
        assert cells[6] == ("" if r[6] is None else repr(r[6])) and float(cells[7]) == r[7]
        assert int(cells[11]) == r[10]


def test_a_gap_longer_than_a_second_is_not_filled(tmp_path):
    first = Recorder([], "first")
    loop = ObserverLoop(Observer.from_model(load_model(MODEL)), _converter, 1 << 16, listeners=[first])
    loop.feed(_sample(0))
    loop.feed(_sample(MAX_FILL + 10))
    assert loop.stats.filled == MAX_FILL - 1 and len(first.rows) == MAX_FILL + 1


def test_the_domain_watch_is_the_converter_the_loop_is_given(capsys):
    """``watch_domain`` wraps the converter before the loop is made (nothing attached afterwards):
    one stderr line the first time Cμ leaves the model's domain; no domain, the converter itself."""
    from rtlift.model.domain import watch_domain

    domain = {"cmu_max": 0.01, "cmu_envelope_max": 0.01, "burst_periods_s": [0.125], "isolated_bursts": True,
              "isolated_after_s": 1.0}
    assert watch_domain(_converter, SimpleNamespace(provenance={}, fs_hz=400.0), "t") is _converter
    first = Recorder([], "first")
    conv = watch_domain(lambda s: (0.02 if s.seq >= 3 else 0.0, 0.0, 0.1), SimpleNamespace(
        provenance={"domain": domain}, fs_hz=400.0), "rtlift observe")
    loop = ObserverLoop(Observer.from_model(load_model(MODEL)), conv, 1 << 16, listeners=[first])
    for seq in range(6):
        loop.feed(_sample(seq))
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("rtlift observe: warning: outside the model's domain at sample 3")
    assert [r[4] for r in first.rows] == [0.0, 0.0, 0.0, 0.02, 0.02, 0.02]
