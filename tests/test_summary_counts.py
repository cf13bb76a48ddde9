"""``observe``/``control`` summaries count every estimate the observer made, whether or not an
estimates file is written (issue 44: ``"estimates": 0`` without ``--out``)."""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from rtlift.app.live import EstimateWriter, ObserverLoop
from rtlift.model.modelfile import load_model
from rtlift.observer import Observer

MODEL = Path(__file__).parent / "data" / "bench_model.json"
SEQS = (0, 1, 2, 5, 6, 7)
"""Six samples received, two missing (3, 4): eight estimates, two of them predict-only."""


@pytest.mark.parametrize("written", [False, True])
def test_estimates_are_counted_with_and_without_an_estimates_file(tmp_path, written):
    writer = EstimateWriter(tmp_path / "e.csv") if written else None
    loop = ObserverLoop(Observer.from_model(load_model(MODEL)), lambda s: (0.0, 0.0, 0.001), 1 << 16,
                        writer=writer)
    for seq in SEQS:
        loop.feed(SimpleNamespace(seq=seq, t_us=seq * 2500, host_time=time.perf_counter()))
    assert (loop.stats.samples, loop.stats.filled, loop.stats.estimates) == (6, 2, 8)
    if written:
        writer.close()
        rows = [r for r in (tmp_path / "e.csv").read_text().splitlines() if r and not r.startswith("#")]
        assert len(rows) - 1 == loop.stats.estimates
