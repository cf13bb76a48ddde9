"""The DAQ firmware's serial side (PROTOCOL.md, "Serial link") on a pseudo-terminal.

Every period it sends one COBS sample packet (seq u16 from ``first_seq``, t_us = 2500 µs
per sample). Streaming begins with one 0x00, as firmware does after reset, so the first
packet is delimited on both sides. Faults per packet (see :mod:`.faults`): a corrupted
packet has one COBS data byte replaced by another non-zero value (the decoded body differs
in exactly one byte, which the CRC-16 always detects); garbage is 1–32 random bytes
followed by 0x00, inserted before a packet.

Protocol version 2 (:mod:`.host_control`): the device reads command packets the host writes
(COBS, 0x00-terminated); it streams version-1 packets until a valid command is applied, then
version-2 packets echoing the applied ``cmd_seq``. While ``stats.cmd_errors`` is nonzero it
sends the event ``"cmd_errors=N"`` (N since start) once a second of its clock. The applied
command and envelope are exposed in :attr:`SerialDaq.control` (the hook for the plant).
Command faults (dropped, corrupted, late; :mod:`.faults`) are decided per command packet,
before the firmware sees it, and counted in ``stats``. Made with ``unread_lost`` (``rtlift
bench serve``), each host that opens the port starts a session from the power-on state
(:meth:`.host_control.HostControl.new_session`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from firmware_io.commands import SERIAL_CMD_SEQ_MODULUS
from firmware_io.serial_codec import MAX_PACKET_BYTES, decode_command, encode_event, encode_sample
from hil_sim.devices.faults import FaultPlan
from hil_sim.devices.host_control import HostControl
from hil_sim.devices.pty_device import FS_HZ, PtyDevice
from hil_sim.devices.source import serial_wire, wire_samples


def cobs_data_positions(frame: bytes) -> list[int]:
    """Indices of the data bytes (not COBS code bytes, not the final 0x00) of a frame."""
    end = len(frame) - 1 if frame.endswith(b"\x00") else len(frame)
    codes = set()
    pos = 0
    while pos < end:
        codes.add(pos)
        pos += frame[pos]
    return [i for i in range(end) if i not in codes]


def corrupt_one_byte(frame: bytes, rng: np.random.Generator) -> bytes:
    """``frame`` with one COBS data byte replaced by another non-zero value (uniform over the
    254 candidates): the decoded body differs in exactly one byte, which the CRC-16 detects."""
    positions = cobs_data_positions(frame)
    pos = positions[int(rng.integers(len(positions)))]
    old = frame[pos]
    new = int(rng.integers(1, 255))
    new = new if new < old else new + 1
    return frame[:pos] + bytes((new,)) + frame[pos + 1:]


def invalid_chunks(data: bytes) -> int:
    """Non-empty runs between 0x00 bytes in ``data`` (which ends with 0x00)."""
    return sum(1 for part in data.split(b"\x00")[:-1] if part)


class SerialDaq(PtyDevice):
    """Emulated serial DAQ: ``SerialDaq(chunks).start()``, then open ``.path`` with pyserial."""

    def __init__(self, chunks: Iterable[object], *, fs_hz: float = FS_HZ, faults: FaultPlan | None = None,
                 seed: int = 0, max_samples: int | None = None, keep_sent: bool = False,
                 first_seq: int = 0, period_us: int | None = None, first_t_us: int = 0,
                 unread_lost: bool = False) -> None:
        super().__init__(wire_samples(chunks, serial_wire), fs_hz=fs_hz, faults=faults, seed=seed,
                         max_samples=max_samples, keep_sent=keep_sent, unread_lost=unread_lost)
        self.first_seq = first_seq
        self.first_t_us = first_t_us
        self.period_us = period_us if period_us is not None else int(round(1e6 / fs_hz))
        self._started = False
        self._in_error = False
        self._events: list[str] = []
        self.control = HostControl(self.stats, SERIAL_CMD_SEQ_MODULUS, self.fs_hz, self.faults, seed)
        """What the host commanded (version 2): the applied command, envelope and watchdog."""
        self._input = bytearray()
        self._samples_per_report = max(1, int(round(self.fs_hz)))

    def on_host(self) -> None:
        """A host opened the port (``unread_lost``): the command side's power-on state, and
        streaming begins again with a 0x00 (the host's first packet delimited)."""
        super().on_host()
        self.control.new_session()
        self._started = False

    def on_unread(self, index: int, sample: tuple[int, int, int, tuple[int, ...]]) -> None:
        """The command side runs on the device clock with nobody there (the watchdog fires)."""
        _, envelope_cv, status, _ = sample
        self.control.step(index, status, envelope_cv)

    def send_event(self, text: str) -> None:
        """Queue a firmware event packet (kind 2); it goes out before the next sample."""
        self._events.append(text)

    def on_input(self, data: bytes) -> None:
        """Command packets from the host: each run between 0x00 bytes is one packet."""
        buf = self._input
        buf += data
        *packets, rest = bytes(buf).split(b"\x00")
        for chunk in packets:
            if chunk:
                self.control.arrive(chunk, self.stats.samples, decode_command, corrupt_one_byte)
        buf[:] = rest
        if len(buf) > MAX_PACKET_BYTES:
            buf.clear()
            self.control.receive(None, self.stats.samples)

    def _packet(self, data: bytes, valid: bool) -> None:
        self.write(data)
        if valid:
            self._in_error = False
        elif not self._in_error:
            self._in_error = True
            self.stats.invalid_runs += 1

    def _emit(self, index: int, sample: tuple[int, int, int, tuple[int, ...]]) -> None:
        st = self.stats
        if not self._started:
            self._started = True
            self.write(b"\x00")
        volt_cv, envelope_cv, status, counts = sample
        cmd_seq, status, envelope_cv = self.control.step(index, status, envelope_cv)
        if st.cmd_errors and index % self._samples_per_report == 0:
            self.send_event(f"cmd_errors={st.cmd_errors}")
        while self._events:
            self._packet(encode_event(self._events.pop(0), self.control.version), True)
            st.events_sent += 1
        seq = (self.first_seq + index) & 0xFFFF
        t_us = (self.first_t_us + index * self.period_us) & 0xFFFFFFFF
        frame = encode_sample(seq, t_us, volt_cv, counts, status, envelope_cv, cmd_seq)
        fault, garbage = self._fault(index)
        if garbage:
            n = int(self.rng.integers(1, 33))
            junk = bytes(self.rng.integers(0, 256, n, dtype=int).tolist()) + b"\x00"
            chunks = invalid_chunks(junk)
            st.garbage_bursts += 1
            st.garbage_chunks += chunks
            if chunks:
                self._packet(junk, False)
            else:
                self.write(junk)
        if fault == "drop":
            st.frames_dropped += 1
            st.samples_lost += 1
            return
        if fault == "corrupt":
            frame = corrupt_one_byte(frame, self.rng)
            self._packet(frame, False)
            st.frames_corrupted += 1
            st.samples_lost += 1
            return
        self._packet(frame, True)
        st.frames_sent += 1
        st.samples_delivered += 1
        if self.sent is not None:
            self.sent.append((seq, t_us, volt_cv, envelope_cv, counts, status, cmd_seq or 0))
        if fault == "duplicate":
            self._packet(frame, True)
            st.frames_sent += 1
            st.frames_duplicated += 1
