"""Whether a live run's commands were applied (issue 44): ``rtlift control`` and ``rtlift record``
end with exit 1 and one line when the device applied too few of the commands the host sent —
a run whose commands the device ignores (a latched watchdog, a device that lost track of the
host's ``cmd_seq``, a link that loses most commands) is no run under the host's control, and its
summary or record must not pass for one.

The rule: at least :data:`MIN_SENT` commands sent and fewer than :data:`APPLIED_SHARE_MIN` of
them applied (``commands_applied`` / ``commands_sent``, the link's exact counters). How the two
were set: a healthy run applies every command it sends (``rtlift control`` one per burst period,
each applied at the next sample; ``rtlift record`` one in flight at a time): the end-to-end
tests measure applied = sent exactly (``tests/test_control_e2e.py``, ``tests/test_record_pty.py``),
and with the command faults the tests inject (a quarter of the commands dropped or corrupted)
about three quarters are applied; the run of issue 44 applied 1 of 49 (2 %). One half lies
between them with a wide margin on either side. Below 4 commands sent a run is too short to
tell (one command in flight when it ended would be a quarter of them). Not more than 4: a
device that ignores commands slows ``rtlift record`` to one command per echo timeout (0.5 s),
so a 3 s experiment sends only about 7 (measured with 90 % of the commands dropped).
"""

from __future__ import annotations

MIN_SENT = 4
APPLIED_SHARE_MIN = 0.5


def commands_not_applied(sent: int, applied: int) -> str | None:
    """``"the device applied A of the S commands sent"`` when ``applied < APPLIED_SHARE_MIN ·
    sent`` with ``sent ≥ MIN_SENT`` (counts of commands, dimensionless), else ``None``."""
    if sent >= MIN_SENT and applied < APPLIED_SHARE_MIN * sent:
        return f"the device applied {applied} of the {sent} commands sent"
    return None
