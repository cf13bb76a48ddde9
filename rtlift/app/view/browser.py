"""Debian's Chromium, headless, as a page on the live view (for the tests and the benchmark).

``HEADLESS_FLAGS`` are the ones a closed machine needs (no sandbox as root, no GPU, none of
Chromium's own network traffic); each run gets a fresh ``--user-data-dir``.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
from pathlib import Path

HEADLESS_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync")


def find_chromium() -> str | None:
    """``$RTLIFT_CHROMIUM``, else ``chromium`` (Debian's package) or a Chrome on ``PATH``; None if none."""
    for candidate in (os.environ.get("RTLIFT_CHROMIUM"), shutil.which("chromium"), "/usr/bin/chromium",
                      shutil.which("chromium-browser"), shutil.which("google-chrome")):
        if candidate and os.access(candidate, os.X_OK):
            return candidate
    return None


class HeadlessPage:
    """``url`` open in a headless Chromium of its own (process group) until :meth:`close`."""

    def __init__(self, url: str, profile_dir: str | os.PathLike, chromium: str | None = None) -> None:
        exe = chromium or find_chromium()
        if exe is None:
            raise FileNotFoundError("Chromium not found (Debian: apt-get install chromium)")
        self.proc = subprocess.Popen([exe, *HEADLESS_FLAGS, f"--user-data-dir={Path(profile_dir)}", url],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)

    def close(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()

    def __enter__(self) -> HeadlessPage:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
