"""A USB–CAN adapter speaking SLCAN (Lawicel ASCII) on a pseudo-terminal, with the DAQ
firmware's CAN side behind it (PROTOCOL.md, "CAN bus"): python-can's real ``slcan``
driver talks to it as to a CANable or a Lawicel CANUSB.

Commands answered (each ends with CR; OK is CR, error is BEL): ``O`` open, ``L`` open
listen-only, ``C`` close, ``S0``–``S8`` bit rate, ``sxxyy`` BTR, ``Y2``/``Y5`` data rate, an
empty command, ``V`` version (``V1013``), ``v`` (``vSL13``), ``N`` serial number
(``NA123``), ``F`` status flags (``F00``), ``Z0``/``Z1`` time stamps, ``M``/``m``
acceptance, ``t``/``T``/``r``/``R`` transmit (``z``/``Z``). While the channel is open every
DAQ sample goes out as three frames ``tIIILDD…`` (0x101, 0x102, 0x103); while it is closed
the DAQ is paused, so no sample is generated unseen.

Protocol version 2 (:mod:`.host_control`): a ``CMD`` frame (0x100) the host transmits is
the DAQ's command; an invalid one (DLC ≠ 8, bad hex, ``cmd_seq`` 0) is counted in
``stats.cmd_errors`` (CAN has no event frame to report it). From the first applied command on,
``FT_FORCE`` echoes its ``cmd_seq`` (u8) and ``ACT``'s status carries bits 4 and 5. The
applied command and envelope are exposed in :attr:`SlcanAdapter.control` (the plant hook).
The DAQ is paused while the channel is closed (its watchdog too), so each open of the channel
starts a host's session from the command side's power-on state
(:meth:`.host_control.HostControl.new_session`, ``stats.sessions``). (Dropping what the last host
left unread with a ``tcflush`` of the slave at ``O`` also dropped the new host's first frames:
tests/test_faults_commands.py received none; a new host skips stale echoes by their ``cmd_seq``.)

Faults per frame (see :mod:`.faults`): drop, duplicate, corrupt (the frame arrives
truncated to 4 data bytes, which the host counts as invalid), garbage (a junk line before
the frame that is no frame command, which the driver ignores). Command faults, per ``CMD``
frame the host transmits, as on the serial DAQ (:meth:`.host_control.HostControl.arrive`):
dropped (the adapter acknowledges the transmit, the DAQ never gets it), corrupted (it reaches
the DAQ truncated to 4 data bytes: DLC ≠ 8, a ``cmd_errors``), or late.
"""

from __future__ import annotations

from collections.abc import Iterable

from firmware_io.can_codec import CMD_ID, DLC, decode_command_frame, encode_sample_frames, load_dbc
from firmware_io.commands import CAN_CMD_SEQ_MODULUS
from hil_sim.devices.faults import FaultPlan
from hil_sim.devices.host_control import HostControl
from hil_sim.devices.pty_device import FS_HZ, PtyDevice
from hil_sim.devices.source import can_wire, wire_samples
from hil_sim.physics import BenchPhysics

OK = b"\r"
ERROR = b"\a"
BITRATE_COMMANDS = {f"S{i}" for i in range(9)}
GARBAGE_ALPHABET = b"0123456789ABCDEFGHIJKLMNOPQSUVWXYZaceghijklmnopqsuvwyz !#$%&*+-./:;<=>?@"
"""Printable junk that never starts a frame line the driver would parse (no t T r R d D b B x)."""


def _truncated(cmd: str, rng: object) -> str:
    """A ``t100…`` line as a corrupted frame reaches the DAQ: its first 4 data bytes, DLC 4."""
    return f"{cmd[:4]}4{cmd[5:13]}"


class SlcanAdapter(PtyDevice):
    """Emulated SLCAN adapter: ``SlcanAdapter(chunks).start()``, then
    ``can.Bus(interface="slcan", channel=adapter.path, bitrate=500000, sleep_after_open=0)``."""

    def __init__(self, chunks: Iterable[object], *, fs_hz: float = FS_HZ, faults: FaultPlan | None = None,
                 seed: int = 0, max_samples: int | None = None, keep_sent: bool = False,
                 first_seq: int = 0, physics: BenchPhysics | None = None,
                 clock_hz: float | None = None) -> None:
        super().__init__(wire_samples(chunks, lambda c: can_wire(c, physics)), fs_hz=fs_hz, faults=faults,
                         seed=seed, max_samples=max_samples, keep_sent=keep_sent)
        self.first_seq = first_seq
        self.is_open = False
        self.listen_only = False
        self.bitrate_command: str | None = None
        self.commands: list[str] = []
        """Every command line the host sent, in order (for tests)."""
        self.frames_from_host: list[str] = []
        self._line = bytearray()
        self._db = load_dbc()
        self._t10_per_sample = int(round(1e5 / (clock_hz or fs_hz)))
        """Device clock per sample in 10 µs (``clock_hz``: the DAQ's rate when paced faster)."""
        self.control = HostControl(self.stats, CAN_CMD_SEQ_MODULUS, self.fs_hz, self.faults, seed)
        """What the host commanded (version 2): the applied command, envelope and watchdog."""

    def streaming(self) -> bool:
        return self.is_open

    # -- the command side ------------------------------------------------------------------
    def on_input(self, data: bytes) -> None:
        for byte in data:
            if byte == 0x0D:
                self._command(self._line.decode("ascii", "replace"))
                self._line.clear()
            elif byte != 0x0A:
                self._line.append(byte)

    def _command(self, cmd: str) -> None:
        self.commands.append(cmd)
        head = cmd[:1]
        reply = ERROR
        if cmd == "":
            reply = OK
        elif cmd in ("O", "L"):
            if not self.is_open:        # a host's session: the DAQ's command side from its power-on state
                self.stats.sessions += 1
                self.control.new_session()
                self.is_open = True
                self.listen_only = cmd == "L"
                reply = OK
        elif cmd == "C":
            self.is_open = False
            reply = OK
        elif cmd in BITRATE_COMMANDS or (head == "s" and len(cmd) == 5) or cmd in ("Y2", "Y5"):
            if not self.is_open:
                self.bitrate_command = cmd
                reply = OK
        elif cmd == "V":
            reply = b"V1013\r"
        elif cmd == "v":
            reply = b"vSL13\r"
        elif cmd == "N":
            reply = b"NA123\r"
        elif cmd == "F":
            reply = b"F00\r"
        elif head in ("Z", "M", "m", "X", "W", "U", "Q"):
            reply = OK
        elif head in ("t", "T", "r", "R", "d", "D", "b", "B"):
            if self.is_open and not self.listen_only:
                self.frames_from_host.append(cmd)
                if cmd[:4] == f"t{CMD_ID:03X}":
                    self._cmd_frame(cmd)
                reply = b"Z\r" if head.isupper() else b"z\r"
        self.write(reply)

    def _cmd_frame(self, cmd: str) -> None:
        """``t100Ldd…``: the host's command to the DAQ behind the adapter, through the command faults."""
        self.control.arrive(cmd, self.stats.samples, self._decode_cmd, _truncated)

    def _decode_cmd(self, cmd: str):
        try:
            dlc = int(cmd[4])
            data = bytes.fromhex(cmd[5:])
        except (ValueError, IndexError):
            return None
        return decode_command_frame(data, self._db) if dlc == DLC == len(data) else None

    # -- the DAQ side ------------------------------------------------------------------------
    def _emit(self, index: int, sample: tuple[int, int, int, tuple[int, ...]]) -> None:
        st = self.stats
        volt_cv, envelope_cv, status, raw = sample
        cmd_seq, status, envelope_cv = self.control.step(index, status, envelope_cv)
        cmd_seq = cmd_seq or 0
        seq = (self.first_seq + index) & 0xFF
        t_10us = (index * self._t10_per_sample) & 0xFFFF
        frames = encode_sample_frames(seq, t_10us, volt_cv, envelope_cv, status, raw[:3], raw[3:], self._db,
                                      cmd_seq)
        out = []
        intact = True
        for arbitration_id, data in frames:
            line = f"t{arbitration_id:03X}8{data.hex().upper()}\r".encode("ascii")
            fault, garbage = self._fault(index)
            if garbage:
                n = int(self.rng.integers(1, 17))
                junk = bytes(GARBAGE_ALPHABET[int(i)] for i in self.rng.integers(0, len(GARBAGE_ALPHABET), n))
                out.append(junk + b"\r")
                st.garbage_bursts += 1
            if fault == "drop":
                st.frames_dropped += 1
                intact = False
                continue
            if fault == "corrupt":
                out.append(f"t{arbitration_id:03X}4{data[:4].hex().upper()}\r".encode("ascii"))
                st.frames_corrupted += 1
                intact = False
                continue
            out.append(line)
            st.frames_sent += 1
            if fault == "duplicate":
                out.append(line)
                st.frames_sent += 1
                st.frames_duplicated += 1
        self.write(b"".join(out))
        if intact:
            st.samples_delivered += 1
            if self.sent is not None:
                self.sent.append((seq, t_10us, volt_cv, envelope_cv, raw, status, cmd_seq))
        else:
            st.samples_lost += 1
