"""The live view (``--view``): headless Chromium on ``rtlift observe`` against the bench on a
pty, and the server's behaviour towards pages that stall or leave."""

from __future__ import annotations

import asyncio
import io
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from hil_sim.devices import SerialDaq
from hil_sim.experiments import daq_stream
from rtlift.app.view import LiveView
from rtlift.app.view.browser import HEADLESS_FLAGS, find_chromium
from rtlift.app.view.server import COUNTER_KEYS
from rtlift.core.errors import UserError
from testkit.lines import line_with

REPO = Path(__file__).resolve().parents[1]
FIGURE = REPO / "docs" / "figures" / "live_view.png"


@pytest.fixture(scope="module")
def browser():
    path = find_chromium()
    if path is None:
        pytest.skip("Chromium not found (apt-get install chromium, as .ci/run does, or set RTLIFT_CHROMIUM)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=path, args=[f for f in HEADLESS_FLAGS if f != "--headless"])
        try:
            yield b
        finally:
            b.close()


def pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def shown_counters(page) -> dict[str, int]:
    return page.evaluate("""() => Object.fromEntries([...document.querySelectorAll('#counters td')]
        .filter((td) => td.dataset.value !== undefined)
        .map((td) => [td.id.slice(2), Number(td.dataset.value)]))""")


def received_above(page, n: int) -> None:
    page.wait_for_function(f"() => Number(document.getElementById('c-received').dataset.value) > {n}",
                           timeout=15_000)


def wait_ended(page) -> str:
    page.wait_for_function("() => document.getElementById('state').textContent.startsWith('ended')",
                           timeout=15_000)
    return page.inner_text("#state")


def open_page(browser, url: str):
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.errors = []
    page.on("pageerror", lambda e: page.errors.append(str(e)))
    page.goto(url)
    return page


@dataclass
class Watched:
    """What the page showed during an 8 s ``rtlift observe --view 0`` on the bench, and the run."""

    returncode: int
    stderr: str
    plots: tuple[bytes, bytes]
    counters: tuple[dict, dict]
    update_rate_hz: float
    state: str
    final: dict[str, int]
    summary: dict
    errors: list[str]
    log: Path


@pytest.fixture(scope="module")
def watched(browser, model_file, tmp_path_factory) -> Watched:
    tmp = tmp_path_factory.mktemp("live_view")
    dev = SerialDaq(daq_stream("random", seed=11))
    with dev:
        proc = subprocess.Popen(
            [sys.executable, "-m", "rtlift", "observe", "--serial", dev.path, "--model", str(model_file),
             "--log", str(tmp / "frames.bin"), "--out", str(tmp / "estimates.csv"),
             "--json", str(tmp / "summary.json"), "--seconds", "8", "--view", "0"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            line = proc.stderr.readline()
            assert "link open" in line, line + proc.stderr.read()
            dev.start()
            line = line_with(proc.stderr, "live view on http://127.0.0.1:")
            page = open_page(browser, line.split()[-1])
            received_above(page, 400)
            plots1, counters1 = page.locator("#plots").screenshot(), shown_counters(page)
            updates1, t1 = int(page.inner_text("#v-updates")), time.monotonic()
            time.sleep(1.0)
            plots2, counters2 = page.locator("#plots").screenshot(), shown_counters(page)
            updates2, t2 = int(page.inner_text("#v-updates")), time.monotonic()
            received_above(page, 2800)
            shot = page.screenshot()                 # for the README: 7 s of the run on the page
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    (tmp / "live_view.png").write_bytes(shot)
    if os.environ.get("RTLIFT_WRITE_FIGURES") == "1":
        FIGURE.write_bytes(shot)
    state = wait_ended(page)
    return Watched(proc.returncode, err, (plots1, plots2), (counters1, counters2),
                   (updates2 - updates1) / (t2 - t1), state, shown_counters(page),
                   json.loads((tmp / "summary.json").read_text()), page.errors, tmp / "frames.bin")


@pytest.mark.pty
def test_the_page_loads_and_its_plot_moves_within_a_second(watched):
    assert watched.returncode == 0, watched.stderr
    a, b = (pixels(p) for p in watched.plots)
    assert a.shape == b.shape
    changed = float(np.mean(np.any(a != b, axis=2)))
    assert changed > 0.01, f"only {changed:.2%} of the plot's pixels changed in 1 s"
    assert watched.errors == []


@pytest.mark.pty
def test_the_counters_shown_move_with_the_link(watched):
    before, after = watched.counters
    assert after["received"] > before["received"]                   # (how many per second: the machine's load)
    assert after["lost"] == 0


@pytest.mark.pty
def test_the_page_keeps_updating(watched):
    assert watched.update_rate_hz > 1.0        # more than one update in the second watched (25 Hz nominal)


@pytest.mark.pty
def test_the_page_ends_on_the_summary_counters(watched):
    """``--seconds 8`` ends on exactly 8 s of the device's samples: 3200 estimates, each a sample
    stepped (or a lost one filled). ``received`` counts every frame the host decoded, and the log
    holds exactly those (the replay below receives as many): frames that came in the same read
    as the 3200th are among them, how many depends on the machine's load (3231 seen under load,
    3233 in a script here), so the count asserted is at least 3200, not equal (issue 44)."""
    assert watched.state == "ended: completed"
    assert watched.final == {k: watched.summary[k] for k in COUNTER_KEYS if k in watched.summary}
    s = watched.summary
    assert watched.final["estimates"] == s["samples_stepped"] + s["samples_filled"] == 3200
    assert watched.final["received"] >= 3200


@pytest.mark.pty
def test_a_realtime_replay_shows_on_the_page_and_ends_on_its_summary(watched, browser, model_file, tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "rtlift", "replay", str(watched.log), "--model", str(model_file), "--realtime",
         "--json", str(tmp_path / "replay.json"), "--view", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = line_with(proc.stderr, "live view on http://127.0.0.1:")
        page = open_page(browser, line.split()[-1])
        received_above(page, 400)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert wait_ended(page) == "ended: ended"
    summary = json.loads((tmp_path / "replay.json").read_text())
    assert shown_counters(page) == {k: summary[k] for k in COUNTER_KEYS if k in summary}
    assert summary["received"] == summary["samples_stepped"] == watched.summary["received"]   # the log: what came


@pytest.mark.pty
def test_sigterm_with_a_page_open_ends_the_run_the_page_and_the_server(browser, model_file, tmp_path):
    dev = SerialDaq(daq_stream("random", seed=12))
    with dev:
        proc = subprocess.Popen(
            [sys.executable, "-m", "rtlift", "observe", "--serial", dev.path, "--model", str(model_file),
             "--json", str(tmp_path / "summary.json"), "--view", "0"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert "link open" in proc.stderr.readline()
            dev.start()
            url = line_with(proc.stderr, "live view on").split()[-1]
            page = open_page(browser, url)
            received_above(page, 400)
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert wait_ended(page) == "ended: terminated"
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert shown_counters(page) == {k: summary[k] for k in COUNTER_KEYS if k in summary}
    port = int(url.rstrip("/").rsplit(":", 1)[1])
    with socket.socket() as s, pytest.raises(ConnectionRefusedError):
        s.connect(("127.0.0.1", port))


def test_rows_are_decimated_and_carry_the_two_sigma_band():
    view = LiveView(0, decimate=4)
    for k in range(8):
        view.tap.append((k, 0.1 if k != 4 else None, 0.2, 0.3, 0.02, 0.25 if k != 4 else math.nan))
    msg = json.loads(view._batch())
    assert msg["t"] == [0.0, 4 / 400]
    assert msg["meas"] == [0.1, None] and msg["nis"] == [0.25, None]
    assert msg["band"][0] == pytest.approx(2 * 0.02 / math.sqrt(0.25))    # 2 √S, S = ν² / NIS
    assert msg["band"][1] is None
    assert len(view.tap) == 0


def test_the_tap_drops_its_oldest_rows_instead_of_growing():
    view = LiveView(0)
    for k in range(3 * view.tap.maxlen):
        view.tap.append((k, 0.0, 0.0, 0.0, 0.0, 1.0))
    assert len(view.tap) == view.tap.maxlen and view.tap[0][0] == 2 * view.tap.maxlen


def test_a_taken_port_is_a_one_line_user_error():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        with pytest.raises(UserError, match=f"cannot listen on 127.0.0.1:{port}"):
            LiveView(port).start()


async def _receive(url: str, seconds: float) -> list[dict]:
    import aiohttp

    got = []
    async with aiohttp.ClientSession() as session, session.ws_connect(url) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            msg = await ws.receive(timeout=seconds)
            got.append(json.loads(msg.data))
    return got


def receive(url: str, seconds: float) -> list[dict]:
    """What a WebSocket client gets in ``seconds`` (in a thread of its own: Playwright's sync
    API may own this thread's event loop)."""
    out: list[list[dict]] = []
    t = threading.Thread(target=lambda: out.append(asyncio.run(_receive(url, seconds))))
    t.start()
    t.join(seconds + 10.0)
    return out[0]


def test_a_stalled_page_and_a_vanished_one_do_not_hold_up_a_live_one():
    """One page connects and never reads, one leaves at once; a third still gets its batches
    at the view's rate, and the producer (the loop's side) never waits."""
    view = LiveView(0, counters=lambda: {"received": 1}).start()
    stop = threading.Event()

    def produce() -> None:
        k = 0
        while not stop.is_set():
            for _ in range(4):
                view.tap.append((k, 0.1, 0.1, 0.1, 0.0, 1.0))
                k += 1
            time.sleep(0.01)

    producer = threading.Thread(target=produce, daemon=True)
    stalled = socket.create_connection(("127.0.0.1", view.port))
    try:
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.sendall(f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{view.port}\r\nUpgrade: websocket\r\n"
                        "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                        "Sec-WebSocket-Version: 13\r\n\r\n".encode())
        with socket.create_connection(("127.0.0.1", view.port)) as vanished:
            vanished.sendall(b"GET /ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                             b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n")
        producer.start()
        got = receive(view.url.replace("http", "ws") + "ws", 2.0)
    finally:
        stop.set()
        producer.join(5)
        view.close()
        stalled.close()
    data = [m for m in got if m["kind"] == "data"]
    assert got[0]["kind"] == "hello"
    assert len(data) >= 40                                  # 25 Hz nominal for 2 s
    assert sum(len(m["t"]) for m in data) > 100
    assert not view._thread.is_alive()
