"""The serial wire format (PROTOCOL.md, "Serial link" and "Version 2"): COBS framing, one
0x00 delimiter per packet, CRC-16/CCITT-FALSE over the decoded body.

Decoded sample packet, version 1 (39 bytes) and version 2 (41 bytes), little-endian::

    version u8 | kind u8 | seq u16 | t_us u32 | volt_cv i16 | fx fy fz tx ty tz i32×6 |
    status u8 | envelope_cv u16 | [version 2: cmd_seq u16 |] crc u16

An event packet is ``version u8 | kind=2 u8 | UTF-8 text | crc u16``; a command (host →
device, version 2) is ``2 | kind=3 | cmd_seq u16 | envelope_cv u16 | burst_period_ms u16 |
flags u8 | watchdog_ms_div10 u8 | crc u16`` (12 bytes). The CRC is
``binascii.crc_hqx(body, 0xFFFF)`` over everything before it.

:class:`SerialDecoder` turns arbitrary byte chunks into :class:`~firmware_io.samples.Sample`
objects and keeps the exact :class:`~firmware_io.samples.Counters`; it never raises on any
input and does no I/O. The counts become N and N·m by the bench's
:class:`~firmware_io.calibration.Calibration` (:meth:`~firmware_io.calibration.Calibration.si_from_counts`),
the one owner of the transducer's scale; the decoder holds none of its own.
"""

from __future__ import annotations

import struct
import time
from binascii import crc_hqx
from collections import deque
from collections.abc import Callable

from cobs import cobs

from firmware_io.calibration import Calibration
from firmware_io.commands import Command
from firmware_io.samples import Counters, EchoCounter, Sample

VERSION = 1
VERSION_2 = 2
VERSIONS = (VERSION, VERSION_2)
KIND_SAMPLE = 1
KIND_EVENT = 2
KIND_COMMAND = 3
SAMPLE_BODY = struct.Struct("<BBHIh6iBH")
"""The 37 bytes covered by the CRC: version kind seq t_us volt_cv counts×6 status envelope_cv."""
CMD_SEQ = struct.Struct("<H")
"""Version 2: the ``cmd_seq`` echoed after the version-1 body (offset 37)."""
CRC = struct.Struct("<H")
SAMPLE_PACKET_LEN = SAMPLE_BODY.size + CRC.size  # 39
SAMPLE_PACKET_LEN_V2 = SAMPLE_BODY.size + CMD_SEQ.size + CRC.size  # 41
SAMPLE_PACKET_LENS = {VERSION: SAMPLE_PACKET_LEN, VERSION_2: SAMPLE_PACKET_LEN_V2}
COMMAND_BODY = struct.Struct("<BBHHHBB")
"""The 10 bytes of a command covered by the CRC."""
COMMAND_PACKET_LEN = COMMAND_BODY.size + CRC.size  # 12
SEQ_MODULUS = 1 << 16
STALE_WINDOW = 8
"""A sample up to this many ``seq`` behind the last one is late (out of order): dropped and
counted in ``duplicates``, since it was already counted lost when the newer one arrived."""
MAX_PACKET_BYTES = 1024
"""A run of bytes longer than this without a delimiter is dropped as one invalid packet."""
DELIMITER = b"\x00"


def _frame(body: bytes) -> bytes:
    return cobs.encode(body + CRC.pack(crc_hqx(body, 0xFFFF))) + DELIMITER


def encode_sample(seq: int, t_us: int, volt_cv: int, counts: tuple[int, ...] | list[int], status: int,
                  envelope_cv: int, cmd_seq: int | None = None) -> bytes:
    """One sample as it travels on the wire: COBS(packet) + 0x00 (values must fit their types).
    Version 1 without ``cmd_seq``, version 2 (41 bytes) with it."""
    version = VERSION if cmd_seq is None else VERSION_2
    body = SAMPLE_BODY.pack(version, KIND_SAMPLE, seq & 0xFFFF, t_us & 0xFFFFFFFF, volt_cv, *counts,
                            status, envelope_cv)
    if cmd_seq is not None:
        body += CMD_SEQ.pack(cmd_seq)
    return _frame(body)


def encode_event(text: str, version: int = VERSION) -> bytes:
    """A firmware event packet (kind 2, UTF-8 text) as it travels on the wire."""
    return _frame(bytes((version, KIND_EVENT)) + text.encode("utf-8"))


def encode_command(cmd_seq: int, envelope_cv: int, burst_period_ms: int = 0, enable: bool = True,
                   watchdog_ms_div10: int = 0) -> bytes:
    """A command packet (PROTOCOL.md, "Command packet") as it travels on the wire: 12 bytes,
    COBS, 0x00. Out-of-range values raise ``ValueError`` (one line naming the field)."""
    cmd = Command(cmd_seq, envelope_cv, burst_period_ms, enable, watchdog_ms_div10)
    return _frame(COMMAND_BODY.pack(VERSION_2, KIND_COMMAND, cmd.cmd_seq, cmd.envelope_cv,
                                    cmd.burst_period_ms, cmd.flags, cmd.watchdog_ms_div10))


def decode_command(chunk: bytes) -> Command | None:
    """The command in ``chunk`` (the COBS bytes between two 0x00), or ``None`` when it is not a
    valid command (bad COBS, length, version, kind or CRC, or ``cmd_seq`` 0). Never raises.
    Flag bits other than bit0 are reserved and ignored."""
    try:
        pkt = cobs.decode(chunk)
    except cobs.DecodeError:
        return None
    if (len(pkt) != COMMAND_PACKET_LEN or pkt[0] != VERSION_2 or pkt[1] != KIND_COMMAND
            or crc_hqx(pkt[:COMMAND_BODY.size], 0xFFFF) != CRC.unpack_from(pkt, COMMAND_BODY.size)[0]):
        return None
    _, _, cmd_seq, envelope_cv, burst_period_ms, flags, watchdog_ms_div10 = COMMAND_BODY.unpack_from(pkt)
    if cmd_seq == 0:
        return None
    return Command(cmd_seq, envelope_cv, burst_period_ms, bool(flags & 1), watchdog_ms_div10)


class SerialDecoder:
    """Incremental decoder: ``feed(bytes)`` delivers complete samples to ``emit``.

    Bytes before the first 0x00 are judged like any packet: a valid one (COBS, version, CRC,
    length) is a sample; one that fails is the tail of a packet joined mid-way, dropped and
    counted as one resync, not as a CRC error. Every non-empty run of
    bytes between two delimiters is one packet: valid, or counted in ``crc_errors``.
    ``lost`` counts the gaps of the u16 ``seq`` between consecutive valid samples (with
    wrap-around); a repeated ``seq``, or one up to :data:`STALE_WINDOW` behind the last (a
    late, out-of-order packet), is counted in ``duplicates`` and dropped.

    Version-1 (39-byte) and version-2 (41-byte) samples may come in one stream (a version-2
    device streams version 1 until the first command); version 2's ``cmd_seq`` goes into
    :attr:`Sample.cmd_seq` and feeds ``commands_applied`` and ``watchdog_trips``. Events of
    either version are accepted; a command packet (kind 3) on the host side is invalid.
    """

    def __init__(self, emit: Callable[[Sample], object], calibration: Calibration | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        self.counters = Counters()
        self.events: deque[str] = deque(maxlen=256)
        self._emit = emit
        self._si = (calibration or Calibration()).si_from_counts
        self._clock = clock or time.perf_counter
        self._echo = EchoCounter(self.counters)
        self._buf = bytearray()
        self._synced = False
        self._partial = False
        self._in_error = False
        self._overflow = False
        self.last_seq: int | None = None

    def restart(self) -> None:
        """A new stream (the device came back): forget buffered bytes, frame sync and the last
        ``seq``; the counters go on."""
        self._buf.clear()
        self._synced = self._partial = self._in_error = self._overflow = False
        self.last_seq = None

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        """Decode every complete packet in ``data`` (plus what was buffered before)."""
        buf = self._buf
        buf += data
        start = 0
        now = self._clock()
        while True:
            end = buf.find(0, start)
            if end < 0:
                break
            if not self._synced:
                self._synced = True
                if self._partial:
                    self.counters.resyncs += 1
                elif end > start:
                    self._first(bytes(buf[start:end]), now)
            elif self._overflow:
                self._overflow = False
                self._invalid()
            elif end > start:
                self._packet(bytes(buf[start:end]), now)
            start = end + 1
        if start:
            del buf[:start]
        if len(buf) > MAX_PACKET_BYTES:
            buf.clear()
            if self._synced:
                self._overflow = True
            else:
                self._partial = True

    def _first(self, chunk: bytes, now: float) -> None:
        """Bytes before the first delimiter: a sample or event when they decode to a valid
        packet (COBS, version, CRC, length), else the tail of a packet joined mid-way — one
        resync, not a CRC error."""
        try:
            pkt = cobs.decode(chunk)
        except cobs.DecodeError:
            pkt = b""
        n = len(pkt)
        if (n >= 4 and pkt[0] in VERSIONS and crc_hqx(pkt[:n - 2], 0xFFFF) == CRC.unpack_from(pkt, n - 2)[0]
                and ((pkt[1] == KIND_SAMPLE and n == SAMPLE_PACKET_LENS[pkt[0]]) or pkt[1] == KIND_EVENT)):
            self._packet(chunk, now)
        else:
            self.counters.resyncs += 1

    def _invalid(self) -> None:
        c = self.counters
        c.crc_errors += 1
        if not self._in_error:
            self._in_error = True
            c.resyncs += 1

    def _packet(self, chunk: bytes, now: float) -> None:
        try:
            pkt = cobs.decode(chunk)
        except cobs.DecodeError:
            self._invalid()
            return
        n = len(pkt)
        if n < 4 or pkt[0] not in VERSIONS or crc_hqx(pkt[:n - 2], 0xFFFF) != CRC.unpack_from(pkt, n - 2)[0]:
            self._invalid()
            return
        kind = pkt[1]
        if kind == KIND_SAMPLE and n == SAMPLE_PACKET_LENS[pkt[0]]:
            self._sample(pkt, now)
        elif kind == KIND_EVENT:
            try:
                text = pkt[2:n - 2].decode("utf-8")
            except UnicodeDecodeError:
                self._invalid()
                return
            self._in_error = False
            self.counters.events += 1
            self.events.append(text)
        else:
            self._invalid()

    def _sample(self, pkt: bytes, now: float) -> None:
        (_, _, seq, t_us, volt_cv, fx, fy, fz, tx, ty, tz, status,
         envelope_cv) = SAMPLE_BODY.unpack_from(pkt)
        cmd_seq = CMD_SEQ.unpack_from(pkt, SAMPLE_BODY.size)[0] if pkt[0] == VERSION_2 else 0
        self._in_error = False
        c = self.counters
        last = self.last_seq
        if last is not None:
            gap = (seq - last) & 0xFFFF
            if gap == 0 or gap >= SEQ_MODULUS - STALE_WINDOW:
                c.duplicates += 1
                return
            c.lost += gap - 1
        self.last_seq = seq
        c.received += 1
        self._echo.see(cmd_seq, status)
        self._emit(Sample(seq, t_us, volt_cv, envelope_cv, self._si(fx, fy, fz, tx, ty, tz), status, now, cmd_seq))
