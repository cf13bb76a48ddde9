"""Link faults the device emulators inject, seeded and counted exactly.

One decision per wire frame (a serial packet, or one CAN frame): with probabilities
``corrupt``, ``drop`` and ``duplicate`` (exclusive), the frame is corrupted, not sent, or sent
twice; independently, with probability ``garbage``, a burst of junk precedes it.
``disconnect_after_s`` closes the device (the pseudo-terminal) after that much streaming.
Only samples with index in ``[start, stop)`` are eligible, so a test can keep a clean tail.

Command faults (protocol version 2, both devices; :class:`.host_control.HostControl`): one
decision per command the host writes (a serial packet or a CAN ``CMD`` frame), with
probabilities ``cmd_drop``, ``cmd_corrupt`` and ``cmd_late`` (exclusive), from a random stream
of their own (the samples' faults are unchanged by them). A dropped command never reaches the
firmware; a corrupted one is invalid when it does (serial: one COBS data byte replaced, so its
CRC-16 always fails; CAN: truncated to 4 data bytes) — counted in ``cmd_errors``, never
applied, never echoed; a late one
reaches the firmware ``cmd_delay_ms`` later (device clock), where it is applied, superseded
or ignored like any other. Eligible while the device's sample index is in ``[start, stop)``.

Spec strings (``--fault``): ``corrupt:rate=1e-3``, ``drop:rate=0.01``, ``duplicate:rate=0.01``,
``garbage:rate=0.01``, ``disconnect:after_s=5``, ``cmd_drop:rate=0.05``,
``cmd_corrupt:rate=0.05``, ``cmd_late:rate=0.05[,delay_ms=50]``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, fields, replace

from rtlift.core.errors import UserError

WIRE_FAULTS: dict[str, str] = {
    "corrupt": "a frame's bytes changed (serial: one COBS data byte, the CRC catches it; CAN: a frame cut to DLC 4)",
    "drop": "a frame never arrives (serial: the packet; CAN: one of the sample's three frames)",
    "duplicate": "a frame sent twice",
    "garbage": "random bytes and a delimiter before a packet (serial)",
    "zero_byte": "a byte inside a packet becomes 0x00 (serial): two invalid packets",
    "truncate": "a packet's tail and delimiter cut (serial): glued to the next packet",
    "late": "a sample arrives after the next one: counted lost, then a stale duplicate",
    "event": "a firmware event packet before the sample (serial)",
    "reorder": "the sample's three frames in another order (CAN)",
    "error_frame": "an error frame before the sample (CAN)",
    "foreign": "another node's frame before the sample (CAN)",
    "flag": "a sensor-fault or ADC-saturated status: received, predicted through",
    "absurd": "forces and torques at the integer limits: received, gated by the observer",
}
"""Every fault on the wire the project injects, by name: the pty devices (:data:`RATE_FAULTS`, at a
rate per frame) and the soak's in-process injectors (:mod:`testkit.wire_faults`) share these names."""
RATE_FAULTS = ("corrupt", "drop", "duplicate", "garbage")
"""The wire faults a pty device injects at a rate (``--fault KIND=RATE``)."""
assert set(RATE_FAULTS) <= set(WIRE_FAULTS)
COMMAND_FAULTS = ("cmd_drop", "cmd_corrupt", "cmd_late")
DEFAULT_CMD_DELAY_MS = 50.0


class FaultSpecError(UserError):
    """A ``--fault`` spec that cannot be parsed."""


@dataclass(frozen=True)
class FaultPlan:
    """Per-frame and per-command fault probabilities, the late commands' delay (ms of the
    device clock) and an optional disconnect time (s of streaming)."""

    corrupt: float = 0.0
    drop: float = 0.0
    duplicate: float = 0.0
    garbage: float = 0.0
    disconnect_after_s: float | None = None
    start: int = 0
    stop: int | None = None
    cmd_drop: float = 0.0
    cmd_corrupt: float = 0.0
    cmd_late: float = 0.0
    cmd_delay_ms: float = DEFAULT_CMD_DELAY_MS

    def __post_init__(self) -> None:
        for name in (*RATE_FAULTS, *COMMAND_FAULTS):
            rate = getattr(self, name)
            if not 0.0 <= rate <= 1.0:
                raise FaultSpecError(f"fault {name}: rate must be in [0, 1], got {rate}")
        if self.corrupt + self.drop + self.duplicate > 1.0:
            raise FaultSpecError("faults: corrupt + drop + duplicate rates exceed 1")
        if self.cmd_drop + self.cmd_corrupt + self.cmd_late > 1.0:
            raise FaultSpecError("faults: cmd_drop + cmd_corrupt + cmd_late rates exceed 1")
        if not self.cmd_delay_ms > 0:
            raise FaultSpecError(f"fault cmd_late: delay_ms must be > 0, got {self.cmd_delay_ms}")
        if self.disconnect_after_s is not None and self.disconnect_after_s < 0:
            raise FaultSpecError(f"fault disconnect: after_s must be >= 0, got {self.disconnect_after_s}")

    @property
    def any(self) -> bool:
        return any(getattr(self, name) > 0 for name in RATE_FAULTS) or self.disconnect_after_s is not None

    @property
    def any_command(self) -> bool:
        return any(getattr(self, name) > 0 for name in COMMAND_FAULTS)

    def command_fault(self, index: int, u: float) -> str | None:
        """``"drop"`` | ``"corrupt"`` | ``"late"`` | ``None`` for a command arriving before
        sample ``index``, given a uniform draw ``u``."""
        if not self.eligible(index):
            return None
        if u < self.cmd_drop:
            return "drop"
        if u < self.cmd_drop + self.cmd_corrupt:
            return "corrupt"
        if u < self.cmd_drop + self.cmd_corrupt + self.cmd_late:
            return "late"
        return None

    def eligible(self, index: int) -> bool:
        return index >= self.start and (self.stop is None or index < self.stop)


def parse_fault(spec: str, plan: FaultPlan | None = None) -> FaultPlan:
    """Add one ``NAME:k=v`` spec to ``plan`` (default: no faults)."""
    plan = plan or FaultPlan()
    name, _, rest = spec.strip().partition(":")
    params: dict[str, float] = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        try:
            if not eq:
                raise ValueError
            params[key.strip()] = float(value)
        except ValueError:
            raise FaultSpecError(f"fault {spec!r}: expected NAME:k=v[,k=v...]") from None
    if name == "cmd_late" and set(params) == {"rate", "delay_ms"}:
        return replace(plan, cmd_late=params["rate"], cmd_delay_ms=params["delay_ms"])
    if name in RATE_FAULTS or name in COMMAND_FAULTS:
        wanted = "rate"
        field_name = name
    elif name == "disconnect":
        wanted = "after_s"
        field_name = "disconnect_after_s"
    else:
        known = ", ".join((*RATE_FAULTS, "disconnect", *COMMAND_FAULTS))
        raise FaultSpecError(f"unknown fault {name!r} (known: {known})")
    if set(params) != {wanted}:
        extra = " (and optionally delay_ms=MS)" if name == "cmd_late" else ""
        raise FaultSpecError(f"fault {name}: give exactly {wanted}=VALUE{extra}, got {spec!r}")
    return replace(plan, **{field_name: params[wanted]})


def parse_faults(specs: Iterable[str]) -> FaultPlan:
    """A plan from several ``--fault`` specs (later ones override earlier ones of a kind)."""
    plan = FaultPlan()
    for spec in specs:
        plan = parse_fault(spec, plan)
    return plan


@dataclass
class DeviceStats:
    """What an emulator did, exactly (the oracle of the link counters in tests).

    ``frames_*`` count wire frames: serial packets, or single CAN frames.
    ``samples_lost`` are samples with a frame dropped or corrupted; ``samples_delivered``
    those whose frames all went out intact. ``garbage_chunks`` (serial) is the number of
    invalid packets the garbage bursts make; ``invalid_runs`` (serial) the runs of
    consecutive invalid packets on the wire (each is one resync for the host).

    Commands (protocol version 2, :mod:`.host_control`): ``commands_valid`` arrived intact
    (``commands_applied`` of them were applied and echoed, ``commands_superseded`` replaced by
    a newer one before the next sample, ``commands_ignored`` not newer than the last);
    ``cmd_errors`` were dropped as invalid; ``watchdog_trips`` times the watchdog fired.
    Command faults: ``commands_dropped`` never reached the firmware, ``commands_corrupted``
    reached it corrupted (each one also in ``cmd_errors``), ``commands_delayed`` reached it
    late (then counted like the others). Every command packet the host wrote is exactly one of
    dropped, corrupted-or-otherwise-invalid (``cmd_errors``), valid, or still delayed.
    ``samples_unread`` (a device made with ``unread_lost``) were sampled while no host had the
    port open, and so never sent; ``sessions`` counts the hosts that opened it (such a device)
    or the SLCAN channel's opens.
    """

    samples: int = 0
    samples_delivered: int = 0
    samples_lost: int = 0
    frames_sent: int = 0
    frames_dropped: int = 0
    frames_corrupted: int = 0
    frames_duplicated: int = 0
    garbage_bursts: int = 0
    garbage_chunks: int = 0
    invalid_runs: int = 0
    events_sent: int = 0
    bytes_sent: int = 0
    commands_valid: int = 0
    commands_applied: int = 0
    commands_superseded: int = 0
    commands_ignored: int = 0
    cmd_errors: int = 0
    commands_dropped: int = 0
    commands_corrupted: int = 0
    commands_delayed: int = 0
    watchdog_trips: int = 0
    samples_unread: int = 0
    sessions: int = 0
    disconnected: bool = False

    def as_dict(self) -> dict[str, int | bool]:
        return {f.name: getattr(self, f.name) for f in fields(self)}
