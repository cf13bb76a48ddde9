"""Helpers shared by the benchmark scripts (not part of the package)."""

from __future__ import annotations

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
