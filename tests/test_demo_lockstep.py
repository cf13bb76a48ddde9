"""The demo's records do not depend on the host's timing (issue 44): recorded through the serial
pty at 10× real time with the device's clock held to the host's (:class:`rtlift.app.demo.Lockstep`),
a host that stalls gives the same records, bit for bit, as one that does not."""

from __future__ import annotations

import random
import time

import numpy as np
import pytest

from rtlift.app import demo
from rtlift.app.demo import DEMO_EFFECT, _Progress, _Tap, record_through_link

pytestmark = pytest.mark.pty

NAMES = ("train_T1p75",)
STALL_S = 0.03
"""A host stall: 120 samples of the device's clock at 10× real time, ≫ the 10-sample lead of a command."""


def _stall(monkeypatch) -> None:
    """The host busy elsewhere after 1 % of the samples it gets (a fixed draw)."""
    rng = random.Random(7)
    recv = _Tap.recv

    def late(self, timeout=None):
        s = recv(self, timeout)
        if rng.random() < 0.01:
            time.sleep(STALL_S)
        return s

    monkeypatch.setattr(_Tap, "recv", late)


def _record(monkeypatch, stalls: bool):
    if stalls:
        _stall(monkeypatch)
    records, _ = record_through_link(NAMES, 1, (DEMO_EFFECT,), 10.0, _Progress(False))
    monkeypatch.undo()
    return records


def test_a_stalling_host_records_the_same_samples_as_a_prompt_one(monkeypatch):
    prompt = _record(monkeypatch, stalls=False)
    stalled = _record(monkeypatch, stalls=True)
    for name in NAMES:
        a, b = prompt[name], stalled[name]
        assert a.meta["commands_late"] == b.meta["commands_late"] == "0"
        for col in ("cmu", "cmu_envelope", "dcl"):
            assert np.array_equal(getattr(a, col), getattr(b, col)), (name, col)
        assert np.array_equal(a.extra["dcl_true"], b.extra["dcl_true"])


def test_without_the_lockstep_the_same_stalls_change_the_record(monkeypatch):
    """The check above can fail: the device free-running, the stalls make commands late."""
    prompt = _record(monkeypatch, stalls=False)
    monkeypatch.setattr(demo.Lockstep, "samples", lambda self, chunks: chunks)
    monkeypatch.setattr(demo.Lockstep, "link", lambda self, link: _Tap(link))
    free = _record(monkeypatch, stalls=True)
    a, b = prompt[NAMES[0]], free[NAMES[0]]
    assert int(b.meta["commands_late"]) > 0
    assert len(a) != len(b) or not np.array_equal(a.cmu_envelope, b.cmu_envelope)
