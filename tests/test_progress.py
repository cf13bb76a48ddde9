"""The progress line of ``identify`` and ``diagnose`` (:mod:`rtlift.app.progress`): on a terminal
only, never with ``--quiet``, and cleared when the work ends."""

from __future__ import annotations

import io
import sys
import time

from rtlift.app.progress import REFRESH_S, working


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_on_a_terminal_the_step_and_its_elapsed_time_are_redrawn_while_it_runs(monkeypatch):
    term = _Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    line = "rtlift identify: identifying the model [00:0"
    with working("rtlift identify", "identifying the model", quiet=False):
        end = time.monotonic() + 20 * REFRESH_S          # a redraw, however loaded the machine
        while term.getvalue().count(line) < 2 and time.monotonic() < end:
            time.sleep(REFRESH_S / 5)
    text = term.getvalue()
    assert text.count(line) >= 2                                              # drawn, then redrawn
    assert text.endswith("\r") or text.endswith("\x1b[A")                     # the line is cleared at the end


def test_quiet_or_not_a_terminal_writes_nothing(monkeypatch):
    for stream, quiet in ((_Terminal(), True), (io.StringIO(), False)):
        monkeypatch.setattr(sys, "stderr", stream)
        with working("rtlift diagnose", "fitting", quiet=quiet):
            time.sleep(REFRESH_S)
        assert stream.getvalue() == ""
