"""Logs for replay, and their reader.

- raw serial capture (``.bin``/``.raw``): the exact bytes read from the port, written as
  they are read and flushed at least every :data:`FLUSH_S` seconds;
- CAN logs (``.asc``, ``.blf``, ``.log``, ``.trc``): python-can's ``can.Logger`` chosen by
  extension, every frame as received;
- record CSV (INTERFACES.md): :class:`RecordWriter`, one row per converted sample;
- command log (``LOG.commands.csv`` beside a frame log): :class:`CommandLog`, every command
  the host sent, with the number of samples it had received when it sent it, so a replay of
  the frames can check that the same samples give the same commands (:func:`read_command_log`).

:func:`read_log` yields the samples of a raw capture or a CAN log through the very same
decoders and counters as a live link, so the same frames in give the same samples out.
:func:`graceful_exit` turns SIGTERM/SIGHUP into ``SystemExit`` so that ``with`` blocks
(links, logs) flush and close on every exit path; Ctrl-C already raises
``KeyboardInterrupt``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from firmware_io.calibration import Calibration
from firmware_io.can_codec import SEQ_MODULUS as CAN_SEQ_MODULUS
from firmware_io.can_codec import CanAssembler
from firmware_io.errors import LogError
from firmware_io.samples import Counters, Sample
from firmware_io.serial_codec import SEQ_MODULUS as SERIAL_SEQ_MODULUS
from firmware_io.serial_codec import SerialDecoder

RAW_SUFFIXES = (".bin", ".raw")
CAN_SUFFIXES = (".asc", ".blf", ".log", ".trc")
FLUSH_S = 0.05
READ_CHUNK = 1 << 16


def log_kind(path: str | os.PathLike) -> str:
    """``"serial"`` for a raw capture, ``"can"`` for a python-can log; else :class:`LogError`."""
    suffix = Path(path).suffix.lower()
    if suffix in RAW_SUFFIXES:
        return "serial"
    if suffix in CAN_SUFFIXES:
        return "can"
    raise LogError(f"{path}: unknown log type {suffix or '(no extension)'!r}: use "
                   f"{'/'.join(RAW_SUFFIXES)} for serial captures, {'/'.join(CAN_SUFFIXES)} for CAN")


class FlushedFile:
    """A log file appended to as data arrives, flushed every ``flush_s`` and on close. A disk
    that fails (full, gone) closes it and raises a one-line :class:`LogError` naming the file
    and ``what`` it holds — never a bare ``OSError``."""

    def __init__(self, path: str | os.PathLike, what: str, *, binary: bool = False,
                 flush_s: float = FLUSH_S) -> None:
        self.path = Path(path)
        self._what = what
        try:
            self._file = (open(path, "wb") if binary  # noqa: SIM115 - closed in close()
                          else open(path, "w", encoding="utf-8", newline=""))
        except OSError as exc:
            raise LogError(f"{path}: cannot write {what} ({exc.strerror})") from None
        self._flush_s = flush_s
        self._last_flush = time.perf_counter()

    def _start(self, meta: dict[str, Any] | None, columns: Iterable[str]) -> None:
        """``# key: value`` metadata lines and the CSV header, on disk at once."""
        self._append("".join(f"# {k}: {v}\n" for k, v in (meta or {}).items()) + ",".join(columns) + "\n")
        self._flush()

    def _append(self, data: str | bytes) -> None:
        try:
            self._file.write(data)
            now = time.perf_counter()
            if now - self._last_flush >= self._flush_s:
                self._file.flush()
                self._last_flush = now
        except OSError as exc:
            raise _failed(self._file, self.path, exc, self._what) from None

    def _flush(self) -> None:
        try:
            self._file.flush()
        except OSError as exc:
            raise _failed(self._file, self.path, exc, self._what) from None

    def close(self) -> None:
        if not self._file.closed:
            try:
                self._file.close()
            except OSError as exc:
                raise _failed(self._file, self.path, exc, self._what) from None

    def __enter__(self) -> FlushedFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RawCapture(FlushedFile):
    """The exact bytes of a serial link, appended as read, flushed every ``flush_s``."""

    def __init__(self, path: str | os.PathLike, flush_s: float = FLUSH_S) -> None:
        super().__init__(path, "log", binary=True, flush_s=flush_s)
        self.bytes_written = 0

    def write(self, data: bytes) -> None:
        """Append ``data``; a failing disk (full, gone) closes the log and raises :class:`LogError`."""
        self._append(data)
        self.bytes_written += len(data)


class CanLog:
    """A python-can log (format by extension); call it with each received message."""

    def __init__(self, path: str | os.PathLike, flush_s: float = FLUSH_S) -> None:
        try:
            self._logger = can.Logger(str(path))
        except (OSError, ValueError) as exc:
            raise LogError(f"{path}: cannot write CAN log ({' '.join(str(exc).split())})") from None
        self.path = Path(path)
        self._flush_s = flush_s
        self._last_flush = time.perf_counter()
        self._closed = False
        self.frames_written = 0

    def __call__(self, msg: can.Message) -> None:
        """Log one frame; a failing disk (full, gone) closes the log and raises :class:`LogError`."""
        try:
            self._logger.on_message_received(msg)
            now = time.perf_counter()
            if now - self._last_flush >= self._flush_s:
                file = getattr(self._logger, "file", None)
                if file is not None and not isinstance(self._logger, can.BLFWriter):
                    file.flush()  # BLF writes compressed containers; it is completed on close
                self._last_flush = now
        except OSError as exc:
            self._closed = True
            raise _failed(self._logger, self.path, exc) from None
        self.frames_written += 1

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._logger.stop()
            except OSError as exc:
                raise _failed(self._logger, self.path, exc) from None

    def __enter__(self) -> CanLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _failed(file: Any, path: Path, exc: OSError, what: str = "log") -> LogError:
    """Close a log whose disk failed (whatever is left in its buffer is lost) and say so in one line."""
    with contextlib.suppress(OSError, ValueError):
        (file.stop if hasattr(file, "stop") else file.close)()
    return LogError(f"{path}: cannot write {what} ({exc.strerror or exc}); the run stopped")


def open_link_log(path: str | os.PathLike, link_kind: str) -> RawCapture | CanLog:
    """The log writer for a link of ``link_kind`` (``"serial"`` or ``"can"``), by extension."""
    kind = log_kind(path)
    if kind != link_kind:
        want = RAW_SUFFIXES if link_kind == "serial" else CAN_SUFFIXES
        raise LogError(f"{path}: a {link_kind} link logs to {'/'.join(want)} files")
    return RawCapture(path) if kind == "serial" else CanLog(path)


class RecordWriter(FlushedFile):
    """A record CSV (INTERFACES.md) written row by row: ``# key: value`` metadata, the
    header ``t,cmu,cmu_envelope,dcl,<extra...>``, flushed every ``flush_s`` and on close."""

    def __init__(self, path: str | os.PathLike, meta: dict[str, Any] | None = None,
                 extra_columns: Iterable[str] = (), flush_s: float = FLUSH_S) -> None:
        super().__init__(path, "record", flush_s=flush_s)
        self.extra_columns = tuple(extra_columns)
        self._start(meta, ("t", "cmu", "cmu_envelope", "dcl", *self.extra_columns))
        self.rows = 0

    def write(self, t: float, cmu: float, cmu_envelope: float, dcl: float, *extra: float) -> None:
        """One row; ``t`` must increase strictly and ``dcl`` be finite (skip missing samples)."""
        if len(extra) != len(self.extra_columns):
            raise ValueError(f"{len(extra)} extra values for {len(self.extra_columns)} extra columns")
        self._append(",".join(repr(float(v)) for v in (t, cmu, cmu_envelope, dcl, *extra)) + "\n")
        self.rows += 1


COMMANDS_SUFFIX = ".commands.csv"
COMMAND_COLUMNS = ("host_s", "after_samples", "cmd_seq", "envelope_cv", "burst_period_ms", "enable",
                   "watchdog_ms_div10")


def commands_path(log_path: str | os.PathLike) -> Path:
    """The command log that goes with the frame log ``log_path``."""
    return Path(f"{log_path}{COMMANDS_SUFFIX}")


@dataclass(frozen=True)
class LoggedCommand:
    """One command as sent: after ``after_samples`` received samples (the host clock aside)."""

    after_samples: int
    cmd_seq: int
    envelope_cv: int
    burst_period_ms: int
    enable: bool
    watchdog_ms_div10: int

    def __str__(self) -> str:
        return (f"cmd_seq {self.cmd_seq} envelope_cv {self.envelope_cv} enable {int(self.enable)} "
                f"after sample {self.after_samples}")


class CommandLog(FlushedFile):
    """Every command a link sent (``LOG.commands.csv``): ``# key: value`` metadata (what a
    replay needs to rerun the controller), then one row per command, flushed every
    ``flush_s`` and on close."""

    def __init__(self, path: str | os.PathLike, meta: dict[str, Any] | None = None,
                 flush_s: float = FLUSH_S) -> None:
        super().__init__(path, "command log", flush_s=flush_s)
        self._start(meta, COMMAND_COLUMNS)
        self.rows = 0

    def write(self, host_s: float, c: LoggedCommand) -> None:
        self._append(f"{host_s:.6f},{c.after_samples},{c.cmd_seq},{c.envelope_cv},{c.burst_period_ms},"
                     f"{int(c.enable)},{c.watchdog_ms_div10}\n")
        self.rows += 1


def read_command_log(log_path: str | os.PathLike) -> tuple[dict[str, str], list[LoggedCommand]] | None:
    """The metadata and commands logged beside ``log_path``; ``None`` if there is no command log,
    :class:`LogError` (one line) if it is not one."""
    path = commands_path(log_path)
    if not path.is_file():
        return None
    meta: dict[str, str] = {}
    rows: list[LoggedCommand] = []
    try:
        with open(path, encoding="utf-8") as fh:
            lines = fh.read().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise LogError(f"{path}: cannot read command log ({getattr(exc, 'strerror', None) or exc})") from None
    header = None
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        if line.startswith("#"):
            key, _, value = line[1:].partition(":")
            meta[key.strip()] = value.strip()
        elif header is None:
            header = tuple(line.split(","))
            if header != COMMAND_COLUMNS:
                raise LogError(f"{path}: not a command log (header {line!r})")
        else:
            try:
                _, after, seq, cv, period, enable, wd = (int(v) if i else float(v)
                                                         for i, v in enumerate(line.split(",")))
            except ValueError:
                raise LogError(f"{path}:{n}: bad command row {line!r}") from None
            rows.append(LoggedCommand(after, seq, cv, period, bool(enable), wd))
    if header is None:
        raise LogError(f"{path}: empty command log")
    return meta, rows


@contextlib.contextmanager
def graceful_exit(signals: Iterable[int] = (signal.SIGTERM, signal.SIGHUP)) -> Iterator[None]:
    """Inside this block, SIGTERM (and SIGHUP) raise ``SystemExit(128 + signum)`` in the main
    thread, so every enclosing ``with`` flushes and closes its files; the previous handlers
    are restored on exit. Outside the main thread it does nothing (signals go there)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _raise(signum: int, frame: object) -> None:
        raise SystemExit(128 + signum)

    previous = {}
    for sig in signals:
        previous[sig] = signal.signal(sig, _raise)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class LogSamples:
    """The samples of a recorded log, decoded as a live link would decode them.

    Iterate once; ``counters``, ``events``, ``kind`` and ``seq_modulus`` as on a link.
    ``host_time`` of each sample is ``time.perf_counter()`` at decoding (a raw capture
    holds no receive times); the device's ``seq`` and ``t_us`` are the clock for replay.
    """

    def __init__(self, path: str | os.PathLike, calibration: Calibration | None = None) -> None:
        self.path = Path(path)
        self.kind = log_kind(path)
        if not self.path.is_file():
            raise LogError(f"{path}: no such log file")
        self.seq_modulus = SERIAL_SEQ_MODULUS if self.kind == "serial" else CAN_SEQ_MODULUS
        self._calibration = calibration or Calibration()
        self._queue: deque[Sample] = deque()
        if self.kind == "serial":
            self._decoder = SerialDecoder(self._queue.append, self._calibration)
            self.counters: Counters = self._decoder.counters
        else:
            self._assembler = CanAssembler()
            self.counters = self._assembler.counters

    @property
    def events(self) -> list[str]:
        return list(self._decoder.events) if self.kind == "serial" else []

    def __iter__(self) -> Iterator[Sample]:
        return self._serial() if self.kind == "serial" else self._can()

    def _serial(self) -> Iterator[Sample]:
        queue = self._queue
        try:
            with open(self.path, "rb") as f:
                while chunk := f.read(READ_CHUNK):
                    self._decoder.feed(chunk)
                    while queue:
                        yield queue.popleft()
        except OSError as exc:
            raise LogError(f"{self.path}: cannot read log ({exc.strerror})") from None

    def _can(self) -> Iterator[Sample]:
        feed = self._assembler.feed_message
        try:
            reader = can.LogReader(str(self.path))
        except (OSError, ValueError) as exc:
            raise LogError(f"{self.path}: cannot read CAN log ({' '.join(str(exc).split())})") from None
        try:
            for msg in reader:
                sample = feed(msg)
                if sample is not None:
                    yield sample
        except (can.CanError, ValueError, IndexError, OSError, EOFError) as exc:
            raise LogError(f"{self.path}: unreadable CAN log ({' '.join(str(exc).split())})") from None
        finally:
            reader.stop()


def read_log(path: str | os.PathLike, calibration: Calibration | None = None) -> LogSamples:
    """The samples of a raw serial capture or a CAN log (by extension); see :class:`LogSamples`."""
    return LogSamples(path, calibration)
