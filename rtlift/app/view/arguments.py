"""``--view [PORT]`` for the commands that run the observer loop."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from rtlift.app.view.server import DEFAULT_PORT, LiveView


def add_view_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--view", nargs="?", const=DEFAULT_PORT, type=int, metavar="PORT",
                        help=f"serve a live plot on http://127.0.0.1:PORT/ (default {DEFAULT_PORT}; "
                             "0: any free port, printed)")


def start_view(args: argparse.Namespace, title: str, fs_hz: float,
               counters: Callable[[], dict[str, Any]] | None = None) -> LiveView | None:
    """The started :class:`LiveView` when ``--view`` was given (its URL on stderr), else None."""
    if args.view is None:
        return None
    view = LiveView(args.view, title=title, fs_hz=fs_hz, counters=counters).start()
    print(f"rtlift: live view on {view.url}", file=sys.stderr, flush=True)
    return view
