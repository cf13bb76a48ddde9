"""The live view's server: an aiohttp app in a daemon thread, fed by a drop-oldest tap.

The 400 Hz loop appends one small tuple per estimate to :attr:`LiveView.tap`, a
``collections.deque(maxlen=TAP_LEN)``: ``append`` never blocks and, once full, drops the
oldest row, so the loop never waits on the view (CPython's deque ``append``/``popleft`` are
atomic, no lock is taken). Every 1/``rate_hz`` s the server thread drains the tap, keeps one
row in ``decimate`` (by sample index) and sends the batch to every page over a WebSocket.
Each page has its own small queue that also drops its oldest batch, so a slow or stalled
browser loses batches while the others and the loop do not notice; one that disconnects is
forgotten. A tap row is::

    (index, ΔCL measured | None, ΔĈL, model ΔCL, ν, NIS)

and the page is sent ``t = index / fs``, the three ΔCL traces, ν, its 2σ = 2 √S with
``S = ν² / NIS`` (the innovation variance; absent when there was no update) and NIS.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import socket
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rtlift.core.errors import UserError
from rtlift.core.rate import FS_HZ

DEFAULT_PORT = 8765
HOST = "127.0.0.1"
STATIC_DIR = Path(__file__).with_name("static")
TAP_LEN = 4096
"""Rows the tap holds (10 s at 400 Hz) before it drops the oldest."""
CLIENT_QUEUE = 8
"""Batches waiting for one page before its oldest is dropped (a third of a second at 25 Hz)."""
COUNTER_KEYS = ("received", "lost", "crc_errors", "resyncs", "duplicates", "events", "reconnects", "estimates")


def _finite(x: float | None) -> float | None:
    return x if x is not None and math.isfinite(x) else None


class LiveView:
    """The page on ``http://127.0.0.1:PORT/`` (``port`` 0: any free port; :attr:`url` says which).

    ``counters`` (settable after start) is called from the server thread at each tick for the
    link counters shown beside the plot; :meth:`close` with the run's summary shows its counters and end state
    as the last word on every page, then stops the server.
    """

    def __init__(self, port: int = DEFAULT_PORT, *, title: str = "rtlift", fs_hz: float = FS_HZ,
                 counters: Callable[[], dict[str, Any]] | None = None, rate_hz: float = 25.0,
                 decimate: int = 4, window_s: float = 30.0) -> None:
        if not 0 <= port <= 65535:
            raise UserError(f"--view: port must be in 0..65535, got {port}")
        self.port = port
        self.title = title
        self.fs_hz = fs_hz
        self.rate_hz = rate_hz
        self.decimate = decimate
        self.window_s = window_s
        self.tap: deque[tuple] = deque(maxlen=TAP_LEN)
        self.counters = counters
        self._history: deque[tuple] = deque(maxlen=int(window_s * fs_hz / decimate))
        self._clients: set[asyncio.Queue] = set()
        self._handlers: set[asyncio.Task] = set()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._final: dict[str, Any] | None = None
        self._linger_s = 1.0
        self._error: BaseException | None = None
        self.stats = {"batches": 0, "rows_sent": 0, "pages": 0, "pages_now": 0, "batches_dropped": 0}

    @property
    def pages_connected(self) -> int:
        """Pages with an open WebSocket now."""
        return len(self._clients)

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}/"

    def start(self) -> LiveView:
        """Bind the port (a one-line :class:`UserError` if it is taken) and serve in a daemon thread."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((HOST, self.port))
            sock.listen(16)
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise UserError(f"--view: cannot listen on {HOST}:{self.port} ({exc.strerror or exc})") from None
        self.port = sock.getsockname()[1]
        self._thread = threading.Thread(target=self._serve, args=(sock,), name="rtlift-view", daemon=True)
        self._thread.start()
        self._ready.wait(10.0)
        if self._error is not None:
            raise RuntimeError(f"live view failed to start: {self._error}")
        return self

    def close(self, final: dict[str, Any] | None = None, linger_s: float = 1.0) -> None:
        """Send ``final`` (a run summary: counters and ``end``) to every page, give them up to
        ``linger_s`` to receive it, and stop the server. Safe to call twice or unstarted."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or not thread.is_alive():
            return
        self._final = final
        self._linger_s = linger_s
        with contextlib.suppress(RuntimeError):          # the loop closed meanwhile
            loop.call_soon_threadsafe(self._stop.set)
        thread.join(linger_s + 3.0)

    def __enter__(self) -> LiveView:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- the server thread -------------------------------------------------------------

    def _serve(self, sock: socket.socket) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._main(sock))
        except BaseException as exc:  # noqa: BLE001 - reported to start(), never to the 400 Hz loop
            self._error = exc
            self._ready.set()
        finally:
            loop.close()
            sock.close()

    async def _main(self, sock: socket.socket) -> None:
        from aiohttp import web

        self._stop = asyncio.Event()
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/favicon.ico", self._no_content)
        app.router.add_static("/static/", STATIC_DIR)
        runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=0.5)
        await runner.setup()
        await web.SockSite(runner, sock).start()
        self._ready.set()
        pump = asyncio.ensure_future(self._pump())
        try:
            await self._stop.wait()
        finally:
            pump.cancel()
            self._broadcast(self._batch())
            self._broadcast(json.dumps(self._final_message()))
            for q in list(self._clients):
                self._offer(q, None)
            if self._handlers:
                await asyncio.wait(list(self._handlers), timeout=self._linger_s)
            for task in list(self._handlers):       # a page that stopped reading
                task.cancel()
            await runner.cleanup()

    async def _index(self, request: Any) -> Any:
        from aiohttp import web

        return web.FileResponse(STATIC_DIR / "index.html")

    async def _no_content(self, request: Any) -> Any:
        from aiohttp import web

        return web.Response(status=204)

    async def _websocket(self, request: Any) -> Any:
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(timeout=0.5)            # close handshake: do not wait on a stalled page
        try:
            await ws.prepare(request)
        except ConnectionError:                             # it left before the handshake was done
            return web.Response(status=400)
        queue: asyncio.Queue = asyncio.Queue(maxsize=CLIENT_QUEUE)
        self.stats["pages"] += 1
        self._clients.add(queue)
        task = asyncio.current_task()
        self._handlers.add(task)

        async def drain_incoming() -> None:
            async for msg in ws:             # the page sends nothing; this notices it leaving
                if msg.type in (WSMsgType.ERROR, WSMsgType.CLOSE):
                    break

        reader = asyncio.ensure_future(drain_incoming())
        try:
            await ws.send_str(json.dumps(self._hello()))
            while not reader.done():
                get = asyncio.ensure_future(queue.get())
                await asyncio.wait({get, reader}, return_when=asyncio.FIRST_COMPLETED)
                if not get.done():
                    get.cancel()
                    break
                text = get.result()
                if text is None:
                    break
                await ws.send_str(text)
        except (ConnectionError, RuntimeError):
            pass                              # the page went away mid-send
        finally:
            reader.cancel()
            self._clients.discard(queue)
            self._handlers.discard(task)
            with contextlib.suppress(Exception):
                await ws.close()
        return ws

    def _hello(self) -> dict[str, Any]:
        return {"kind": "hello", "title": self.title, "fs_hz": self.fs_hz, "decimate": self.decimate,
                "rate_hz": self.rate_hz, "window_s": self.window_s,
                **self._columns(list(self._history)), "counters": self._read_counters()}

    async def _pump(self) -> None:
        period = 1.0 / self.rate_hz
        while True:
            await asyncio.sleep(period)
            self._broadcast(self._batch())

    def _batch(self) -> str:
        """Drain the tap into one message: the decimated rows and the counters now."""
        tap, rows, d = self.tap, [], self.decimate
        while True:
            try:
                row = tap.popleft()
            except IndexError:
                break
            if row[0] % d == 0:
                rows.append(row)
        self._history.extend(rows)
        self.stats["batches"] += 1
        self.stats["rows_sent"] += len(rows)
        return json.dumps({"kind": "data", **self._columns(rows), "counters": self._read_counters()})

    def _columns(self, rows: list[tuple]) -> dict[str, list]:
        fs = self.fs_hz
        t, meas, est, model, innov, band, nis = [], [], [], [], [], [], []
        for index, z, dcl, model_dcl, nu, q in rows:
            t.append(index / fs)
            meas.append(_finite(z))
            est.append(_finite(dcl))
            model.append(_finite(model_dcl))
            innov.append(_finite(nu))
            nis.append(_finite(q))
            band.append(2.0 * abs(nu) / math.sqrt(q) if q is not None and q > 0 and math.isfinite(q)
                        and math.isfinite(nu) else None)
        return {"t": t, "meas": meas, "est": est, "model": model, "innov": innov, "band": band, "nis": nis}

    def _read_counters(self) -> dict[str, int]:
        if self.counters is None:
            return {}
        c = self.counters()
        return {k: int(c[k]) for k in COUNTER_KEYS if k in c}

    def _final_message(self) -> dict[str, Any]:
        f = self._final or {}
        counters = {k: int(f[k]) for k in COUNTER_KEYS if k in f} if f else self._read_counters()
        return {"kind": "final", "end": f.get("end", "closed"), "counters": counters,
                "latency_p50_ms": f.get("latency_p50_ms"), "latency_p99_ms": f.get("latency_p99_ms")}

    def _broadcast(self, text: str) -> None:
        self.stats["pages_now"] = len(self._clients)
        for q in list(self._clients):
            self._offer(q, text)

    def _offer(self, queue: asyncio.Queue, item: str | None) -> None:
        """Put ``item`` on one page's queue, dropping that page's oldest batch if it is full."""
        if queue.full():
            with contextlib.suppress(asyncio.QueueEmpty):
                queue.get_nowait()
                self.stats["batches_dropped"] += 1
        queue.put_nowait(item)
