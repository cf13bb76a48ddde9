"""ΔCL references for ``rtlift control`` (INTERFACES.md): ``steps:V@T,V@T,...`` (ΔCL ``V``
from time ``T`` s; 0 before the first step), ``sine:mean=M,amp=A,hz=F``, or a CSV file with
columns ``t``, ``dcl_ref`` (linear between rows, the end values held). Time is in seconds
from the start of tracking. :func:`parse_reference` raises :class:`UserError` (one line)."""

from __future__ import annotations

import csv
import math
import os
from bisect import bisect_right
from dataclasses import dataclass

from rtlift.core.errors import UserError


@dataclass(frozen=True)
class Reference:
    """A reference ``r(t)``: piecewise-linear through ``(t, value)`` points (``steps``: held
    from each point on), or a sine."""

    kind: str
    t: tuple[float, ...] = ()
    value: tuple[float, ...] = ()
    mean: float = 0.0
    amp: float = 0.0
    hz: float = 0.0

    def at(self, t: float) -> float:
        """r(t) (no allocation)."""
        if self.kind == "sine":
            return self.mean + self.amp * math.sin(2.0 * math.pi * self.hz * t)
        ts, vs = self.t, self.value
        j = bisect_right(ts, t) - 1
        if self.kind == "steps":
            return vs[j] if j >= 0 else 0.0
        if j < 0:
            return vs[0]
        if j >= len(ts) - 1:
            return vs[-1]
        return vs[j] + (vs[j + 1] - vs[j]) * (t - ts[j]) / (ts[j + 1] - ts[j])

    @property
    def peak(self) -> float:
        return self.mean + abs(self.amp) if self.kind == "sine" else max(self.value)


def _number(text: str, what: str, spec: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise UserError(f"--reference {spec!r}: {what} is not a number: {text.strip()!r}") from None
    if not math.isfinite(v):
        raise UserError(f"--reference {spec!r}: {what} must be finite")
    return v


def _steps(spec: str, body: str) -> Reference:
    points = []
    for item in filter(None, (s.strip() for s in body.split(","))):
        v, at, t = item.partition("@")
        if not at:
            raise UserError(f"--reference {spec!r}: expected V@T, got {item!r}")
        points.append((_number(t, "time", spec), _number(v, "value", spec)))
    if not points:
        raise UserError(f"--reference {spec!r}: give at least one step V@T")
    ts = [p[0] for p in points]
    if any(b <= a for a, b in zip(ts, ts[1:], strict=False)) or ts[0] < 0:
        raise UserError(f"--reference {spec!r}: step times must be >= 0 and increasing")
    return Reference("steps", tuple(ts), tuple(p[1] for p in points))


def _sine(spec: str, body: str) -> Reference:
    given: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in body.split(","))):
        k, eq, v = item.partition("=")
        k = k.strip()
        if not eq or k not in ("mean", "amp", "hz"):
            raise UserError(f"--reference {spec!r}: expected mean=M,amp=A,hz=F, got {item!r}")
        given[k] = _number(v, k, spec)
    missing = [k for k in ("mean", "amp", "hz") if k not in given]
    if missing:
        raise UserError(f"--reference {spec!r}: missing {', '.join(missing)}")
    if given["hz"] <= 0:
        raise UserError(f"--reference {spec!r}: hz must be positive")
    return Reference("sine", mean=given["mean"], amp=given["amp"], hz=given["hz"])


def _csv(path: str) -> Reference:
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except OSError as exc:
        raise UserError(f"{path}: cannot read reference ({exc.strerror or exc})") from None
    if not rows or not {"t", "dcl_ref"} <= set(rows[0]):
        raise UserError(f"{path}: a reference CSV needs columns t and dcl_ref and at least one row")
    ts, vs = [], []
    for i, row in enumerate(rows, start=2):
        try:
            t, v = float(row["t"]), float(row["dcl_ref"])
        except (TypeError, ValueError):
            raise UserError(f"{path}: line {i}: t and dcl_ref must be numbers") from None
        if not (math.isfinite(t) and math.isfinite(v)):
            raise UserError(f"{path}: line {i}: t and dcl_ref must be finite")
        ts.append(t)
        vs.append(v)
    if any(b <= a for a, b in zip(ts, ts[1:], strict=False)):
        raise UserError(f"{path}: t must be strictly increasing")
    return Reference("table", tuple(ts), tuple(vs))


def parse_reference(spec: str) -> Reference:
    """``steps:...`` | ``sine:...`` | a CSV path → :class:`Reference`."""
    head, colon, body = spec.partition(":")
    if colon and head == "steps":
        return _steps(spec, body)
    if colon and head == "sine":
        return _sine(spec, body)
    if os.path.exists(spec) or spec.endswith(".csv"):
        return _csv(spec)
    raise UserError(f"--reference {spec!r}: expected steps:V@T,..., sine:mean=M,amp=A,hz=F or a CSV file")
