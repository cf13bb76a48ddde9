"""The DAQ's sample rate (PROTOCOL.md): one named constant instead of ``400.0`` in every layer."""

from __future__ import annotations

FS_HZ = 400.0
"""Samples per second of the DAQ, the bench and the observer (Hz)."""

PERIOD_S = 1.0 / FS_HZ
"""One sample period (s)."""
