"""The serial wire format (PROTOCOL.md, "Serial link"): COBS framing, one 0x00 delimiter
per packet, CRC-16/CCITT-FALSE over the decoded body.

Decoded sample packet (39 bytes, little-endian)::

    version u8 | kind u8 | seq u16 | t_us u32 | volt_cv i16 | fx fy fz tx ty tz i32×6 |
    status u8 | envelope_cv u16 | crc u16

An event packet is ``version u8 | kind=2 u8 | UTF-8 text | crc u16``. The CRC is
``binascii.crc_hqx(body, 0xFFFF)`` over everything before it.

:class:`SerialDecoder` turns arbitrary byte chunks into :class:`~firmware_io.samples.Sample`
objects and keeps the exact :class:`~firmware_io.samples.Counters`; it never raises on any
input and does no I/O.
"""

from __future__ import annotations

import struct
import time
from binascii import crc_hqx
from collections import deque
from collections.abc import Callable

from cobs import cobs

from firmware_io.samples import Counters, Sample

VERSION = 1
KIND_SAMPLE = 1
KIND_EVENT = 2
SAMPLE_BODY = struct.Struct("<BBHIh6iBH")
"""The 37 bytes covered by the CRC: version kind seq t_us volt_cv counts×6 status envelope_cv."""
CRC = struct.Struct("<H")
SAMPLE_PACKET_LEN = SAMPLE_BODY.size + CRC.size  # 39
SEQ_MODULUS = 1 << 16
STALE_WINDOW = 8
"""A sample up to this many ``seq`` behind the last one is late (out of order): dropped and
counted in ``duplicates``, since it was already counted lost when the newer one arrived."""
MAX_PACKET_BYTES = 1024
"""A run of bytes longer than this without a delimiter is dropped as one invalid packet."""
DELIMITER = b"\x00"


def encode_sample(seq: int, t_us: int, volt_cv: int, counts: tuple[int, ...] | list[int], status: int,
                  envelope_cv: int) -> bytes:
    """One sample as it travels on the wire: COBS(packet) + 0x00 (values must fit their types)."""
    body = SAMPLE_BODY.pack(VERSION, KIND_SAMPLE, seq & 0xFFFF, t_us & 0xFFFFFFFF, volt_cv, *counts,
                            status, envelope_cv)
    return cobs.encode(body + CRC.pack(crc_hqx(body, 0xFFFF))) + DELIMITER


def encode_event(text: str) -> bytes:
    """A firmware event packet (kind 2, UTF-8 text) as it travels on the wire."""
    body = bytes((VERSION, KIND_EVENT)) + text.encode("utf-8")
    return cobs.encode(body + CRC.pack(crc_hqx(body, 0xFFFF))) + DELIMITER


class SerialDecoder:
    """Incremental decoder: ``feed(bytes)`` delivers complete samples to ``emit``.

    Bytes before the first 0x00 are judged like any packet: a valid one (COBS, version, CRC,
    length) is a sample; one that fails is the tail of a packet joined mid-way, dropped and
    counted as one resync, not as a CRC error. Every non-empty run of
    bytes between two delimiters is one packet: valid, or counted in ``crc_errors``.
    ``lost`` counts the gaps of the u16 ``seq`` between consecutive valid samples (with
    wrap-around); a repeated ``seq``, or one up to :data:`STALE_WINDOW` behind the last (a
    late, out-of-order packet), is counted in ``duplicates`` and dropped.
    """

    def __init__(self, emit: Callable[[Sample], object], counts_per_n: float = 1.0e6,
                 counts_per_nm: float = 1.0e9, clock: Callable[[], float] | None = None) -> None:
        self.counters = Counters()
        self.events: deque[str] = deque(maxlen=256)
        self._emit = emit
        self._cpn = float(counts_per_n)
        self._cpnm = float(counts_per_nm)
        self._clock = clock or time.perf_counter
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
        if (n >= 4 and pkt[0] == VERSION and crc_hqx(pkt[:n - 2], 0xFFFF) == CRC.unpack_from(pkt, n - 2)[0]
                and ((pkt[1] == KIND_SAMPLE and n == SAMPLE_PACKET_LEN) or pkt[1] == KIND_EVENT)):
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
        if n < 4 or pkt[0] != VERSION or crc_hqx(pkt[:n - 2], 0xFFFF) != CRC.unpack_from(pkt, n - 2)[0]:
            self._invalid()
            return
        kind = pkt[1]
        if kind == KIND_SAMPLE and n == SAMPLE_PACKET_LEN:
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
        cpn = self._cpn
        cpnm = self._cpnm
        self._emit(Sample(seq, t_us, volt_cv, envelope_cv,
                          (fx / cpn, fy / cpn, fz / cpn, tx / cpnm, ty / cpnm, tz / cpnm), status, now))
