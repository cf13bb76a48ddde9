"""The CAN wire format (PROTOCOL.md, "CAN bus" and "Version 2"): three 8-byte frames per
sample and the host's ``CMD`` frame, described by the DBC file shipped in this package
(``rtlift_daq.dbc``) and coded with cantools.

:class:`CanAssembler` collects the frames ``ACT`` (0x101), ``FT_FORCE`` (0x102) and
``FT_TORQUE`` (0x103) by their u8 ``seq``; a sample is complete when all three arrived.
An incomplete sample is counted lost when a newer ``seq`` completes (the gap of ``seq``
with wrap at 256). No I/O; never raises on any frame. Version 2: ``FT_FORCE``'s last byte
carries the ``cmd_seq`` (u8) of the last applied command, ``ACT``'s status bits 4 and 5 host
control and watchdog; a version-1 device sends 0 there, so one assembler reads both.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import cache
from pathlib import Path

import cantools
from cantools.database.can import Database

from firmware_io.commands import Command, check_can_cmd_seq
from firmware_io.samples import Counters, EchoCounter, Sample

DBC_PATH = Path(__file__).with_name("rtlift_daq.dbc")
CMD_ID = 0x100
ACT_ID = 0x101
FT_FORCE_ID = 0x102
FT_TORQUE_ID = 0x103
FRAME_IDS = (ACT_ID, FT_FORCE_ID, FT_TORQUE_ID)
SEQ_MODULUS = 256
DLC = 8
PENDING_WINDOW = 8
"""Incomplete samples up to this many ``seq`` ahead of the last complete one are kept; frames
up to this many ``seq`` behind it are late (out of order) and dropped as duplicates."""


@cache
def load_dbc() -> Database:
    """The package's DBC (parsed once; treat it as read-only)."""
    return cantools.database.load_file(str(DBC_PATH))


def encode_sample_frames(seq: int, t_10us: int, volt_cv: int, envelope_cv: int, status: int,
                         force_raw: tuple[int, int, int], torque_raw: tuple[int, int, int],
                         db: Database | None = None, cmd_seq: int = 0) -> list[tuple[int, bytes]]:
    """The three frames ``(arbitration_id, data)`` of one sample, raw DBC values
    (forces in 0.001 N, torques in 0.00001 N·m, i16; the caller saturates); ``cmd_seq`` is
    the last applied command's (version 2; its low byte travels)."""
    db = db or load_dbc()
    seq &= 0xFF
    act = db.get_message_by_frame_id(ACT_ID).encode(
        {"seq": seq, "volt_cv": volt_cv, "envelope_cv": envelope_cv, "status": status,
         "t_10us": t_10us & 0xFFFF}, scaling=False)
    fx, fy, fz = force_raw
    tx, ty, tz = torque_raw
    force = db.get_message_by_frame_id(FT_FORCE_ID).encode(
        {"seq": seq, "fx": fx, "fy": fy, "fz": fz, "cmd_seq": cmd_seq & 0xFF}, scaling=False)
    torque = db.get_message_by_frame_id(FT_TORQUE_ID).encode(
        {"seq": seq, "tx": tx, "ty": ty, "tz": tz, "spare": 0}, scaling=False)
    return [(ACT_ID, bytes(act)), (FT_FORCE_ID, bytes(force)), (FT_TORQUE_ID, bytes(torque))]


def encode_command_frame(cmd_seq: int, envelope_cv: int, burst_period_ms: int = 0, enable: bool = True,
                         watchdog_ms_div10: int = 0, db: Database | None = None) -> tuple[int, bytes]:
    """The ``CMD`` frame ``(0x100, data)`` of a command (PROTOCOL.md, "CAN (version 2)"):
    ``cmd_seq`` is a u8, never 0. Out-of-range values raise ``ValueError`` (one line)."""
    check_can_cmd_seq(cmd_seq)
    cmd = Command(cmd_seq, envelope_cv, burst_period_ms, enable, watchdog_ms_div10)
    db = db or load_dbc()
    data = db.get_message_by_frame_id(CMD_ID).encode(
        {"cmd_seq": cmd.cmd_seq, "envelope_cv": cmd.envelope_cv, "burst_period_ms": cmd.burst_period_ms,
         "flags": cmd.flags, "watchdog_ms_div10": cmd.watchdog_ms_div10, "spare": 0}, scaling=False)
    return CMD_ID, bytes(data)


def decode_command_frame(data: bytes | bytearray, db: Database | None = None) -> Command | None:
    """The command in a ``CMD`` frame's data, or ``None`` when it is not valid (DLC ≠ 8 or
    ``cmd_seq`` 0). Never raises; flag bits other than bit0 are reserved and ignored."""
    if len(data) != DLC or data[0] == 0:
        return None
    db = db or load_dbc()
    d = db.get_message_by_frame_id(CMD_ID).decode(bytes(data), decode_choices=False, scaling=False)
    return Command(d["cmd_seq"], d["envelope_cv"], d["burst_period_ms"], bool(d["flags"] & 1),
                   d["watchdog_ms_div10"])


class CanAssembler:
    """Frames in, samples out: ``feed(arbitration_id, data)`` returns the completed
    :class:`Sample` or ``None``.

    Counters: a frame of our identifiers with a DLC other than 8, or an error frame, is a
    ``crc_errors``; a frame whose (identifier, ``seq``) was already received for a pending
    sample, or whose ``seq`` is that of the last completed sample or up to
    :data:`PENDING_WINDOW` behind it (late, out of order), is a ``duplicates`` and dropped;
    ``lost`` grows by the ``seq`` gap − 1 each time a sample completes. The first sample is
    judged like any other: complete (all three frames, any order) it is delivered; the
    frames of samples still incomplete when the first one completes (the bus joined
    mid-sample) are dropped and counted as one ``resyncs``. Frames of other
    identifiers (other nodes on the bus), remote and extended frames are ignored.
    """

    def __init__(self, db: Database | None = None, clock: Callable[[], float] | None = None) -> None:
        db = db or load_dbc()
        self.counters = Counters()
        self._act = db.get_message_by_frame_id(ACT_ID)
        self._force = db.get_message_by_frame_id(FT_FORCE_ID)
        self._torque = db.get_message_by_frame_id(FT_TORQUE_ID)
        self._clock = clock or time.perf_counter
        self._echo = EchoCounter(self.counters)
        self._pending: dict[int, list] = {}
        self.last_seq: int | None = None

    def restart(self) -> None:
        """A new stream (the device came back): forget pending frames and the last ``seq``;
        the counters go on."""
        self._pending.clear()
        self.last_seq = None

    def feed_message(self, msg: object) -> Sample | None:
        """Feed one ``can.Message`` (error frames counted; remote and extended ignored)."""
        if msg.is_error_frame:
            self.counters.crc_errors += 1
            return None
        if msg.is_remote_frame or msg.is_extended_id:
            return None
        return self.feed(msg.arbitration_id, msg.data)

    def feed(self, arbitration_id: int, data: bytes | bytearray) -> Sample | None:
        """Feed one standard data frame."""
        if arbitration_id == ACT_ID:
            slot = 0
        elif arbitration_id == FT_FORCE_ID:
            slot = 1
        elif arbitration_id == FT_TORQUE_ID:
            slot = 2
        else:
            return None
        c = self.counters
        if len(data) != DLC:
            c.crc_errors += 1
            return None
        seq = data[0]
        last = self.last_seq
        if last is not None and ((last - seq) & 0xFF) <= PENDING_WINDOW:
            c.duplicates += 1
            return None
        parts = self._pending.get(seq)
        if parts is None:
            parts = self._pending[seq] = [None, None, None]
        elif parts[slot] is not None:
            c.duplicates += 1
            return None
        if slot == 0:
            parts[0] = self._act.decode(data, decode_choices=False, scaling=False)
        elif slot == 1:
            parts[1] = self._force.decode(data, decode_choices=False)
        else:
            parts[2] = self._torque.decode(data, decode_choices=False)
        if parts[0] is None or parts[1] is None or parts[2] is None:
            return None
        del self._pending[seq]
        if last is not None:
            c.lost += ((seq - last) & 0xFF) - 1
        elif self._pending:
            c.resyncs += 1  # frames of a sample joined mid-way before the first complete one
        self.last_seq = seq
        if self._pending:
            for p in [p for p in self._pending if ((p - seq) & 0xFF) > PENDING_WINDOW]:
                del self._pending[p]
        c.received += 1
        act, force, torque = parts
        cmd_seq = int(force["cmd_seq"])
        self._echo.see(cmd_seq, act["status"])
        return Sample(seq, act["t_10us"] * 10, act["volt_cv"], act["envelope_cv"],
                      (force["fx"], force["fy"], force["fz"], torque["tx"], torque["ty"], torque["tz"]),
                      act["status"], self._clock(), cmd_seq)
