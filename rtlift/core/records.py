"""Record files: one experiment per CSV, sampled uniformly (INTERFACES.md, "Record files").

Lift records (:class:`Record`: ``t, cmu, cmu_envelope, dcl``) and generic single-input records
(:class:`SisoRecord`: ``t, u, y``, any system) share one parser and its one-line errors.

``# key: value`` lines before the header are metadata; the header names the columns; the
required columns are ``t`` (s), ``cmu``, ``cmu_envelope`` and ``dcl``; any other column is
kept in :attr:`Record.extra`. Reading validates everything and raises :class:`RecordError`
with a one-line message naming the file, line and column.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtlift.core.errors import RecordError
from rtlift.core.textfile import read_text

REQUIRED = ("t", "cmu", "cmu_envelope", "dcl")
SISO_REQUIRED = ("t", "u", "y")



def sample_rate(meta: dict[str, str], t: np.ndarray) -> float:
    """A record's sample rate: its ``fs_hz`` metadata if present, else from the median time step."""
    if "fs_hz" in meta:
        return float(meta["fs_hz"])
    return float(1.0 / np.median(np.diff(t)))


def burst_onsets(cmu: np.ndarray, threshold: float | None = None) -> np.ndarray:
    """Sample indices where Cμ rises above ``threshold`` (default: half its maximum)."""
    cmu = np.asarray(cmu, dtype=float)
    thr = 0.5 * float(np.max(cmu)) if threshold is None else threshold
    on = cmu > thr
    return np.flatnonzero(on[1:] & ~on[:-1]) + 1 if on.size > 1 else np.empty(0, int)


@dataclass
class Record:
    """One experiment: uniformly sampled arrays of equal length."""

    t: np.ndarray
    cmu: np.ndarray
    cmu_envelope: np.ndarray
    dcl: np.ndarray
    meta: dict[str, str] = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    name: str = "record"

    def __post_init__(self) -> None:
        n = len(self.t)
        for col in ("cmu", "cmu_envelope", "dcl"):
            if len(getattr(self, col)) != n:
                raise ValueError(f"column {col!r} has {len(getattr(self, col))} samples, t has {n}")
        for col, arr in self.extra.items():
            if len(arr) != n:
                raise ValueError(f"column {col!r} has {len(arr)} samples, t has {n}")

    def __len__(self) -> int:
        return len(self.t)

    @property
    def fs_hz(self) -> float:
        """Sample rate: the ``fs_hz`` metadata if present, else from the median time step."""
        return sample_rate(self.meta, self.t)

    def slice(self, start: int, stop: int) -> Record:
        """Samples ``start:stop`` as a new record (metadata kept)."""
        return Record(
            self.t[start:stop], self.cmu[start:stop], self.cmu_envelope[start:stop],
            self.dcl[start:stop], dict(self.meta),
            {k: v[start:stop] for k, v in self.extra.items()}, self.name,
        )


def _fail(path: str | os.PathLike, line: int, message: str) -> RecordError:
    return RecordError(f"{path}:{line}: {message}")


def _read_table(path: str | os.PathLike, required: tuple[str, ...], min_samples: int
                ) -> tuple[dict[str, str], dict[str, np.ndarray]]:
    """Metadata and columns of a record CSV with the ``required`` columns, validated
    (finite, ``t`` strictly increasing); :class:`RecordError` (one line) on any problem."""
    text = read_text(path, "a record file", RecordError)

    lines = text.splitlines()
    meta: dict[str, str] = {}
    i = 0
    while i < len(lines) and (lines[i].startswith("#") or not lines[i].strip()):
        body = lines[i][1:].strip() if lines[i].startswith("#") else ""
        if ":" in body:
            key, value = body.split(":", 1)
            meta[key.strip()] = value.strip()
        i += 1
    if i >= len(lines):
        raise _fail(path, i, f"no header line (expected columns {','.join(required)})")
    header_line = i + 1
    header = [h.strip() for h in next(csv.reader([lines[i]]))]
    for col in required:
        if col not in header:
            raise _fail(path, header_line, f"column '{col}' is missing from the header")
    ncol = len(header)
    rows = list(csv.reader(io.StringIO("\n".join(lines[i + 1:]))))
    data = np.empty((len(rows), ncol))
    n = 0
    for r, row in enumerate(rows):
        lineno = header_line + 1 + r
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != ncol:
            raise _fail(path, lineno, f"{len(row)} cells, the header has {ncol}")
        for c, cell in enumerate(row):
            try:
                v = float(cell)
            except ValueError:
                raise _fail(path, lineno, f"column '{header[c]}': not a number: {cell.strip()!r}") from None
            if header[c] in required and not math.isfinite(v):
                raise _fail(path, lineno, f"column '{header[c]}': {cell.strip()} is not a finite number")
            data[n, c] = v
        n += 1
    data = data[:n]
    if n < min_samples:
        raise _fail(path, header_line, f"{n} samples, at least {min_samples} needed")
    cols = {h: data[:, c].copy() for c, h in enumerate(header)}
    dt = np.diff(cols["t"])
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise _fail(path, _data_line(rows, header_line, k), "column 't': not strictly increasing")
    return meta, cols


def read_record(path: str | os.PathLike, min_samples: int = 2) -> Record:
    """Read and validate a record CSV; raise :class:`RecordError` (one line) on any problem."""
    meta, cols = _read_table(path, REQUIRED, min_samples)
    extra = {h: v for h, v in cols.items() if h not in REQUIRED}
    return Record(cols["t"], cols["cmu"], cols["cmu_envelope"], cols["dcl"], meta, extra, Path(path).stem)


@dataclass
class SisoRecord:
    """A generic single-input record (any system): input ``u`` and output ``y`` in any units."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    meta: dict[str, str] = field(default_factory=dict)
    name: str = "record"

    def __len__(self) -> int:
        return len(self.t)

    @property
    def fs_hz(self) -> float:
        """Sample rate: the ``fs_hz`` metadata if present, else from the median time step."""
        return sample_rate(self.meta, self.t)


def read_siso_record(path: str | os.PathLike, min_samples: int = 2) -> SisoRecord:
    """Read and validate a generic record CSV (columns ``t``, ``u``, ``y``)."""
    meta, cols = _read_table(path, SISO_REQUIRED, min_samples)
    return SisoRecord(cols["t"], cols["u"], cols["y"], meta, Path(path).stem)


def record_kind(path: str | os.PathLike) -> str:
    """``"lift"`` or ``"siso"`` from the header of a record file (``"lift"`` when unsure: its
    reader then says what is missing)."""
    try:
        with open(path, encoding="utf-8") as f:
            for line in f:
                if line.startswith("#") or not line.strip():
                    continue
                cols = {c.strip() for c in line.split(",")}
                return "siso" if set(SISO_REQUIRED) <= cols and "cmu" not in cols else "lift"
    except (OSError, UnicodeDecodeError):
        pass
    return "lift"


def write_siso_record(path: str | os.PathLike, record: SisoRecord) -> None:
    """Write a generic record CSV (metadata, header ``t,u,y``, full float precision)."""
    with open(path, "w", encoding="utf-8", newline="") as f:
        for key, value in record.meta.items():
            f.write(f"# {key}: {value}\n")
        f.write("t,u,y\n")
        np.savetxt(f, np.column_stack([record.t, record.u, record.y]), delimiter=",", fmt="%.17g")


def _data_line(rows: list[list[str]], header_line: int, k: int) -> int:
    """File line number of the k-th non-blank data row."""
    seen = -1
    for r, row in enumerate(rows):
        if row and any(c.strip() for c in row):
            seen += 1
            if seen == k:
                return header_line + 1 + r
    return header_line + 1 + k


def write_record(path: str | os.PathLike, record: Record) -> None:
    """Write a record CSV (metadata, header, one row per sample, full float precision)."""
    cols = [("t", record.t), ("cmu", record.cmu), ("cmu_envelope", record.cmu_envelope),
            ("dcl", record.dcl), *record.extra.items()]
    with open(path, "w", encoding="utf-8", newline="") as f:
        for key, value in record.meta.items():
            f.write(f"# {key}: {value}\n")
        f.write(",".join(name for name, _ in cols) + "\n")
        table = np.column_stack([np.asarray(v, dtype=float) for _, v in cols])
        np.savetxt(f, table, delimiter=",", fmt="%.17g")


RUNS = "runs"
"""A joined record's metadata key (:func:`join_runs`): JSON ``[[stem, first sample], …]``, one per run."""


def join_runs(recs: list[SisoRecord]) -> SisoRecord:
    """Several generic records of one system as one record of several runs, each its own
    experiment from rest (``rtlift diagnose --train A --train B``): u, y concatenated, time
    continued, each run's stem and first sample in ``meta[RUNS]`` (:func:`split_runs` gives them back;
    every fit treats each run from rest, one cost); named by the stems joined with ``+``."""
    fs = recs[0].fs_hz
    starts = np.cumsum([0] + [len(r) for r in recs[:-1]])
    t = np.concatenate([r.t - r.t[0] + k / fs for r, k in zip(recs, starts, strict=True)])
    meta = {"fs_hz": repr(fs), RUNS: json.dumps([[r.name, int(k)] for r, k in zip(recs, starts, strict=True)])}
    return SisoRecord(t, np.concatenate([r.u for r in recs]), np.concatenate([r.y for r in recs]), meta,
                      "+".join(r.name for r in recs))


def split_runs(rec: SisoRecord) -> list[SisoRecord]:
    """The runs of a record :func:`join_runs` made (each under its own stem); any other record alone."""
    if RUNS not in rec.meta:
        return [rec]
    runs = json.loads(rec.meta[RUNS])
    bounds = [k for _, k in runs] + [len(rec)]
    meta = {k: v for k, v in rec.meta.items() if k != RUNS}
    return [SisoRecord(rec.t[lo:hi], rec.u[lo:hi], rec.y[lo:hi], dict(meta), name)
            for (name, lo), hi in zip(runs, bounds[1:], strict=True)]
