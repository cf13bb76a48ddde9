"""Progress on stderr for commands that compute for many seconds (``identify``, ``diagnose``):
the step running and the seconds spent on it, redrawn twice a second by a tqdm line (as
``record`` and ``demo`` draw theirs). Off with ``--quiet`` and when stderr is not a terminal
(tqdm's ``disable=None``), so pipes and logs get only the summary."""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

REFRESH_S = 0.5


@contextmanager
def working(command: str, step: str, quiet: bool = False) -> Iterator[None]:
    """``rtlift COMMAND: STEP [mm:ss]`` on stderr while the block runs, cleared when it ends."""
    from tqdm import tqdm

    bar = tqdm(total=None, desc=f"{command}: {step}", bar_format="{desc} [{elapsed}]", file=sys.stderr,
               leave=False, disable=True if quiet else None)
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(REFRESH_S):
            bar.refresh()

    ticker = None if bar.disable else threading.Thread(target=tick, name="progress", daemon=True)
    if ticker is not None:
        ticker.start()
    try:
        yield
    finally:
        stop.set()
        if ticker is not None:
            ticker.join()
        bar.close()
