"""A gust: an additive lift disturbance on the truth plant (``--gust F:A,...``).

    ΔCL_true(t) = ΔCL_plant(t) + Σ_i A_i sin(2π F_i t)

with ``t`` the device clock from power-up (sample index / fs, s), ``F_i`` in Hz and ``A_i`` in
ΔCL. It is part of the bench's truth (``BenchRun.dcl_true``, ``HilStream.truth``) and so of
the measured forces: what a gust or wake buffeting does to a wing, which lift control is for.
It is not an effect of the model's world (:mod:`hil_sim.effects`): no diagnosis names it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hil_sim import FS_HZ
from rtlift.core.errors import UserError

MAX_AMPLITUDE = 0.5
"""Largest amplitude accepted (ΔCL): the static map spans 0.22."""


@dataclass(frozen=True)
class Gust:
    """Sines ``(F_i Hz, A_i)`` added to the true ΔCL: :meth:`at` gives Σ A_i sin(2π F_i t)."""

    lines: tuple[tuple[float, float], ...] = ()

    def at(self, t: np.ndarray) -> np.ndarray:
        """The disturbance at the times ``t`` (s)."""
        t = np.asarray(t, dtype=float)
        out = np.zeros(t.shape)
        for f, a in self.lines:
            out += a * np.sin(2.0 * math.pi * f * t)
        return out

    def spec(self) -> str:
        """The canonical ``F:A,...`` (round-trips through :func:`parse_gust`)."""
        return ",".join(f"{f:g}:{a:g}" for f, a in self.lines)

    def __bool__(self) -> bool:
        return bool(self.lines)


def parse_gust(spec: str | None, fs_hz: float = FS_HZ) -> Gust:
    """``F:A[,F:A...]`` (Hz : ΔCL) → :class:`Gust`; ``None`` or ``""`` → no gust. A bad spec
    raises :class:`~rtlift.core.errors.UserError` (one line)."""
    if spec is None or not spec.strip():
        return Gust()
    lines = []
    for item in spec.split(","):
        f_text, colon, a_text = item.strip().partition(":")
        if not colon:
            raise UserError(f"--gust {spec!r}: expected F:A (Hz:ΔCL), got {item.strip()!r}")
        try:
            f, a = float(f_text), float(a_text)
        except ValueError:
            raise UserError(f"--gust {spec!r}: {item.strip()!r} is not two numbers F:A") from None
        if not (math.isfinite(f) and 0.0 < f < fs_hz / 2.0):
            raise UserError(f"--gust {spec!r}: frequency must be in (0, {fs_hz / 2.0:g}) Hz, got {f_text.strip()}")
        if not (math.isfinite(a) and 0.0 < a <= MAX_AMPLITUDE):
            raise UserError(f"--gust {spec!r}: amplitude must be in (0, {MAX_AMPLITUDE:g}], got {a_text.strip()}")
        lines.append((f, a))
    return Gust(tuple(lines))
