"""``rtlift plot RUN``: the figures ``rtlift demo`` draws, for a run after the fact.

``RUN`` is an estimates CSV (``rtlift observe --out`` or ``rtlift replay --out``: the columns of
:data:`rtlift.app.live.COLUMNS`) or a frame log (``.bin``/``.raw`` serial, ``.asc``/``.blf``/…
CAN), which is first replayed through the observer of ``--model`` exactly as ``rtlift replay``
does. Written to ``--out`` (default: beside RUN), :mod:`rtlift.app.figures`:

- ``NAME_observer.png``: measured ΔCL, the estimate ΔĈL and the open-loop model;
- ``NAME_innovation.png``: the innovation with its predicted ±2σ band, and the NIS;
- ``NAME_control.png`` for a log written by ``rtlift control`` (its ``LOG.commands.csv`` beside
  it): the reference, the estimate and the commanded envelope. The reference's time starts
  after the settle and the tare, as in ``rtlift control``; the estimates start after the settle.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
from pathlib import Path

import numpy as np

from rtlift.core.errors import UserError
from rtlift.core.textfile import read_text

CSV_COLUMNS = ("t", "dcl", "dcl_hat", "model_dcl", "innovation", "nis")
"""Columns of the estimates file the figures need."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plot", help="the demo's figures of an observe/control/replay run, after the fact",
                              description="Draw the figures the demo draws (measured ΔCL, estimate, open-loop "
                                          "model, innovation and NIS; reference and commanded envelope for a "
                                          "control run) from an estimates CSV (observe/replay --out) or a frame "
                                          "log replayed with --model.")
    p.add_argument("run", metavar="RUN", help="estimates CSV, or a frame log (.bin/.raw serial, .asc/.blf CAN)")
    p.add_argument("--model", metavar="MODEL.json", help="with a frame log: the model to replay it through")
    p.add_argument("--out", metavar="DIR", help="directory for the PNG files (default: beside RUN)")
    p.set_defaults(func=run)


def read_estimates(path: str | os.PathLike) -> tuple[dict[str, str], dict[str, np.ndarray]]:
    """``# key: value`` metadata and the :data:`CSV_COLUMNS` of an estimates file (empty cells → NaN);
    :class:`UserError` (one line) if it is not one."""
    lines = read_text(path, "an estimates file", UserError,
                      ": an estimates CSV, or a frame log with --model").splitlines()
    meta: dict[str, str] = {}
    i = 0
    while i < len(lines) and (lines[i].startswith("#") or not lines[i].strip()):
        key, colon, value = lines[i][1:].partition(":")
        if colon:
            meta[key.strip()] = value.strip()
        i += 1
    if i >= len(lines):
        raise UserError(f"{path}: no header line (an estimates file has columns {','.join(CSV_COLUMNS)})")
    header = [h.strip() for h in next(csv.reader([lines[i]]))]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise UserError(f"{path}:{i + 1}: not an estimates file: column(s) {', '.join(missing)} missing "
                        "(rtlift observe --out or rtlift replay --out writes one)")
    where = [header.index(c) for c in CSV_COLUMNS]
    rows = []
    for n, row in enumerate(csv.reader(lines[i + 1:]), i + 2):
        if not row:
            continue
        if len(row) != len(header):
            raise UserError(f"{path}:{n}: {len(row)} cells, the header has {len(header)}")
        try:
            rows.append([float(row[k]) if row[k].strip() else math.nan for k in where])
        except ValueError:
            raise UserError(f"{path}:{n}: not a number in {row!r}") from None
    if len(rows) < 2:
        raise UserError(f"{path}: {len(rows)} estimate row(s), at least 2 needed")
    data = np.asarray(rows)
    return meta, {c: data[:, k] for k, c in enumerate(CSV_COLUMNS)}


def _replay(log: str, model: str, csv_path: str) -> None:
    """``rtlift replay LOG --model M --out CSV`` (its summary lines printed as it prints them)."""
    from rtlift.app.cli import build_parser

    args = build_parser().parse_args(["replay", log, "--model", model, "--out", csv_path])
    code = args.func(args)
    if code == 130:
        raise KeyboardInterrupt
    if code != 0:
        print(f"rtlift plot: note: rtlift replay ended with status {code}; plotting its estimates")


def _control(log: str, t: np.ndarray, fs_hz: float):
    """(reference per estimate, command times, envelope V) of a log ``rtlift control`` wrote; ``None`` otherwise."""
    from firmware_io.calibration import Calibration
    from firmware_io.logs import read_command_log
    from rtlift.app.closed_loop import SETTLE_S
    from rtlift.app.reference import parse_reference

    logged = read_command_log(log)
    if logged is None or logged[0].get("tool") != "rtlift control" or "reference" not in logged[0]:
        return None
    meta, commands = logged
    tare_s = Calibration().tare_seconds
    reference = parse_reference(meta["reference"])
    ref = np.array([reference.at(x - tare_s) if x >= tare_s else math.nan for x in t])
    t_cmd = np.array([c.after_samples / fs_hz - SETTLE_S for c in commands])
    env = np.array([c.envelope_cv / 100.0 if c.enable else 0.0 for c in commands])
    return ref, t_cmd, env


def run(args: argparse.Namespace) -> int:
    import tempfile

    from rtlift.app.figures import control_figure, innovation_figure, observer_figure

    path = Path(args.run)
    if not path.exists():
        raise UserError(f"{args.run}: no such file")
    out = Path(args.out) if args.out else path.parent
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{out}: cannot create output directory ({exc.strerror})") from None
    is_log = path.suffix.lower() != ".csv"
    if is_log:
        if not args.model:
            raise UserError(f"{args.run}: a frame log is replayed through a model: give --model MODEL.json "
                            "(or plot the estimates CSV of observe/replay --out)")
        with tempfile.TemporaryDirectory() as tmp:
            est = os.path.join(tmp, "estimates.csv")
            _replay(str(path), args.model, est)
            _, cols = read_estimates(est)
    else:
        _, cols = read_estimates(path)
    t = cols["t"]
    fs = 1.0 / float(np.median(np.diff(t)))         # t = index / fs
    name = path.stem
    written = []
    title = f"{path.name}: {len(t)} estimates ({len(t) / fs:.1f} s)"
    p = out / f"{name}_observer.png"
    observer_figure(t, cols["dcl"], cols["dcl_hat"], cols["model_dcl"], str(p), title, fs)
    written.append(p)
    p = out / f"{name}_innovation.png"
    innovation_figure(t, cols["innovation"], cols["nis"], str(p), title, fs)
    written.append(p)
    ctl = _control(str(path), t, fs) if is_log else None
    if ctl is not None:
        ref, t_cmd, env = ctl
        p = out / f"{name}_control.png"
        control_figure(t, ref, [("estimate ΔĈL", "tab:blue", t, cols["dcl_hat"], t_cmd, env)], str(p),
                       f"{title}; reference and commands", fs)
        written.append(p)
    print(f"rtlift plot: {', '.join(str(w) for w in written)}")
    return 0
