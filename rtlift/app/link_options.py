"""The command line's link options (``--serial PORT`` / ``--can INTERFACE:CHANNEL``, ``--reconnect``)
and the link config they give (:func:`firmware_io.links.link_config`)."""

from __future__ import annotations

import argparse
from typing import Any

from firmware_io.errors import LinkError
from firmware_io.links import link_config


def add_link_arguments(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """Add the mutually exclusive ``--serial PORT`` / ``--can INTERFACE:CHANNEL`` options."""
    group = parser.add_mutually_exclusive_group(required=required)
    group.add_argument("--serial", metavar="PORT", help="serial port or pyserial URL of the DAQ")
    group.add_argument("--can", metavar="INTERFACE:CHANNEL",
                       help="python-can interface and channel, e.g. slcan:/dev/ttyACM0")


def add_live_arguments(parser: argparse.ArgumentParser) -> None:
    """Add what a command running the observer live on a link reads: the link
    (:func:`add_link_arguments`), ``--model`` (the model file with observer settings),
    ``--calibration`` (the bench's when absent) and ``--log`` (the raw frame log)."""
    add_link_arguments(parser)
    parser.add_argument("--model", required=True, metavar="MODEL.json", help="model file with observer settings")
    parser.add_argument("--calibration", metavar="FILE", help="calibration TOML (default: the bench's)")
    parser.add_argument("--log", metavar="FILE", help="raw frame log: .bin/.raw (serial) or .asc/.blf (CAN)")


def add_reconnect_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--reconnect [GIVE_UP_S]`` (read by :func:`link_config_from_args`)."""
    parser.add_argument("--reconnect", nargs="?", const=-1.0, type=float, metavar="GIVE_UP_S",
                        help="when the device vanishes, reopen it with backoff (for ever, or give up after "
                             "GIVE_UP_S seconds) and go on with the same log and summary")


def link_config_from_args(args: argparse.Namespace, **extra: Any) -> dict[str, Any]:
    """The link config from options added by :func:`add_link_arguments` (and
    :func:`add_reconnect_argument`); :class:`LinkError` for a negative give-up time."""
    give_up = getattr(args, "reconnect", None)
    if give_up is not None:
        if give_up != -1.0 and not give_up >= 0:
            raise LinkError(f"--reconnect: give-up time must be >= 0 seconds, got {give_up}")
        extra.setdefault("reconnect", True if give_up == -1.0 else {"give_up_s": give_up})
    return link_config(getattr(args, "serial", None), getattr(args, "can", None), **extra)
