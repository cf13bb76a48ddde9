"""A device on a new pseudo-terminal, paced by a thread at the DAQ rate.

The pty is created at construction (``os.openpty``, raw mode); ``path`` is the slave's name
for the host to open. ``start()`` runs the device thread: it answers what the host writes
and emits one sample per period on absolute deadlines (``deadline += period``; it waits
``max(0, deadline − perf_counter())`` in ``select`` so host commands are served meanwhile).
``stop()`` ends the thread and closes the pty: for the host the device is gone.

With ``unread_lost`` the device keeps no end of the slave open itself, so it can see (a
hang-up on the master) whether a host has the port open: like a USB DAQ whose clock runs
whether or not anybody reads it, what it samples while nobody has the port open is lost
(``stats.samples_unread``) instead of waiting in the pty's buffer; its command side still
runs on the device clock meanwhile (:meth:`PtyDevice.on_unread`: the watchdog fires with
nobody there), and each host that opens the port starts a session (:meth:`PtyDevice.on_host`,
``stats.sessions``).
"""

from __future__ import annotations

import errno
import os
import select
import termios
import threading
import time
import tty
from abc import ABC, abstractmethod
from collections.abc import Iterator

import numpy as np

from hil_sim.devices.faults import DeviceStats, FaultPlan
from rtlift.core.rate import FS_HZ

MAX_LATE_S = 0.5
"""A device later than this behind its schedule (host not reading) restarts its clock
instead of bursting out the backlog."""


class PtyDevice(ABC):
    """Base of the emulators: pty, pacing thread, faults, exact statistics."""

    def __init__(self, samples: Iterator[tuple[int, int, int, tuple[int, ...]]], *, fs_hz: float = FS_HZ,
                 faults: FaultPlan | None = None, seed: int = 0, max_samples: int | None = None,
                 keep_sent: bool = False, unread_lost: bool = False) -> None:
        self._samples = samples
        self.fs_hz = float(fs_hz)
        self.faults = faults or FaultPlan()
        self.rng = np.random.default_rng(seed)
        self.max_samples = max_samples
        self.stats = DeviceStats()
        self.sent: list[tuple] | None = [] if keep_sent else None
        """With ``keep_sent``: the wire values of every sample delivered intact, in order."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._master)
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._hangup = None
        self._host_away = True
        if unread_lost:
            os.close(self._slave)
            self._slave = None
            self._hangup = select.poll()
            self._hangup.register(self._master, select.POLLHUP)
        self._stop = threading.Event()
        self.finished = threading.Event()
        """Set when the device stops streaming (source exhausted, max_samples, disconnect, stop);
        until ``stop()`` it still answers what the host writes."""
        self._thread: threading.Thread | None = None
        self._fd_lock = threading.Lock()
        self.error: BaseException | None = None

    # -- life cycle ----------------------------------------------------------------------
    def start(self) -> PtyDevice:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=type(self).__name__, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """End the thread and close the pty (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._close_fds()
        self.finished.set()

    def disconnect(self) -> None:
        """Vanish like an unplugged USB device: close the pty now."""
        self.stats.disconnected = True
        self._stop.set()
        self._close_fds()

    @property
    def host_open(self) -> bool:
        """Whether a host has the port open, as the device thread last saw it (a device made
        with ``unread_lost``; ``False`` otherwise)."""
        return self._hangup is not None and not self._host_away

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the device stopped streaming; ``True`` if it did."""
        return self.finished.wait(timeout)

    def __enter__(self) -> PtyDevice:
        """``with device:`` guarantees ``stop()``; streaming begins at ``start()``."""
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _close_fds(self) -> None:
        with self._fd_lock:
            for name in ("_master", "_slave"):
                fd = getattr(self, name)
                if fd is not None:
                    setattr(self, name, None)
                    try:
                        os.close(fd)
                    except OSError:
                        pass

    # -- the device thread ---------------------------------------------------------------
    def _run(self) -> None:
        period = 1.0 / self.fs_hz
        disconnect_at = (None if self.faults.disconnect_after_s is None
                         else int(round(self.faults.disconnect_after_s * self.fs_hz)))
        deadline = time.perf_counter()
        try:
            while not self._stop.is_set():
                now = time.perf_counter()
                master = self._master
                if master is None:
                    break
                if self.finished.is_set():  # done streaming: still answer the host until stop()
                    if select.select([master], [], [], 0.05)[0]:
                        self._serve_input()
                    continue
                hung_up = self._hangup is not None and bool(self._hangup.poll(0))   # no host: nothing to read
                if self._hangup is not None and hung_up != self._host_away:
                    if hung_up:
                        self._host_left(master)
                    else:
                        self.on_host()              # a host opened the port: before anything it wrote
                    self._host_away = hung_up
                readable, _, _ = select.select([] if hung_up else [master], [], [], max(0.0, deadline - now))
                if readable:
                    self._serve_input()
                    continue
                if not self.streaming():
                    deadline = time.perf_counter() + period
                    continue
                if time.perf_counter() - deadline > MAX_LATE_S:
                    deadline = time.perf_counter()
                index = self.stats.samples
                if disconnect_at is not None and index >= disconnect_at:
                    self.disconnect()
                    break
                if self.max_samples is not None and index >= self.max_samples:
                    self.finished.set()
                    continue
                try:
                    sample = next(self._samples)
                except StopIteration:
                    self.finished.set()
                    continue
                self.stats.samples += 1
                if self._hangup is not None and self._host_away:    # as seen above: a host that opened
                    self.stats.samples_unread += 1      # since gets its session first; nobody there: lost
                    self.on_unread(index, sample)
                else:
                    self._emit(index, sample)
                deadline += period
        except OSError as exc:
            if exc.errno not in (errno.EIO, errno.EBADF):
                self.error = exc
            self.stats.disconnected = True
        except Exception as exc:  # noqa: BLE001 - reported through .error, never lost in a thread
            self.error = exc
        finally:
            self.finished.set()

    def _serve_input(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO and self._hangup is not None:
                return                      # the host closed the port: not gone, nobody there
            raise
        if data:
            self.on_input(data)

    def _host_left(self, master: int) -> None:
        """The host closed the port: what it wrote last is still served, then what it left
        unread is flushed, so that the next host reads nothing of this session."""
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:                 # EIO: nothing more the host wrote
                break
            if not data:
                break
            self.on_input(data)
        termios.tcflush(master, termios.TCIOFLUSH)

    def write(self, data: bytes) -> None:
        """Write all of ``data`` to the host, waiting while the pty buffer is full."""
        view = memoryview(data)
        while view:
            master = self._master
            if master is None or self._stop.is_set():
                return
            try:
                n = os.write(master, view)
            except BlockingIOError:
                select.select([], [master], [], 0.1)
                continue
            view = view[n:]
        self.stats.bytes_sent += len(data)

    # -- what concrete devices define ----------------------------------------------------
    def streaming(self) -> bool:
        """Whether the DAQ clock runs now (the SLCAN adapter pauses while its channel is closed)."""
        return True

    def on_input(self, data: bytes) -> None:
        """Bytes the host wrote (ignored unless the device speaks a command protocol)."""
        return None

    def on_host(self) -> None:
        """A host opened the port (a device made with ``unread_lost``): a new session."""
        self.stats.sessions += 1

    def on_unread(self, index: int, sample: tuple[int, int, int, tuple[int, ...]]) -> None:
        """Sample ``index`` was taken while no host had the port open (never sent)."""
        return None

    @abstractmethod
    def _emit(self, index: int, sample: tuple[int, int, int, tuple[int, ...]]) -> None:
        """Send sample number ``index`` with the fault plan applied."""

    def _fault(self, index: int) -> tuple[str | None, bool]:
        """(``"corrupt"`` | ``"drop"`` | ``"duplicate"`` | ``None``, garbage burst before?)."""
        f = self.faults
        if not f.any or not f.eligible(index):
            return None, False
        u = self.rng.random()
        garbage = f.garbage > 0 and self.rng.random() < f.garbage
        if u < f.corrupt:
            return "corrupt", garbage
        if u < f.corrupt + f.drop:
            return "drop", garbage
        if u < f.corrupt + f.drop + f.duplicate:
            return "duplicate", garbage
        return None, garbage

