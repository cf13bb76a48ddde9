"""Helpers shared by the benchmark scripts (not part of the package)."""

from __future__ import annotations

import contextlib
import io
import json
import platform
import sys

import numpy as np


def percentiles_us(samples_s: np.ndarray) -> tuple[float, float]:
    """Median and 99th percentile of durations given in seconds, in µs."""
    s = np.asarray(samples_s) * 1e6
    return float(np.median(s)), float(np.percentile(s, 99))


def emit(result: dict) -> None:
    """Print the benchmark's result as one JSON object on the last line."""
    result.setdefault("python", sys.version.split()[0])
    result.setdefault("machine", platform.machine())
    print(json.dumps(result, sort_keys=True))


def run_cli(*argv) -> str:
    """``rtlift ARGV`` in process; its stdout; a non-zero exit raises."""
    from rtlift.app.cli import main as rtlift

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = rtlift([str(a) for a in argv])
    if code != 0:
        raise RuntimeError(f"rtlift {' '.join(map(str, argv))} exited {code}")
    return buf.getvalue()
