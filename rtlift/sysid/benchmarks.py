"""The measured nonlinear benchmarks vendored in the repository's ``data/`` (``data/README.md``)
and their official splits: the one place that knows how each ``.npz`` is cut into estimation and
test data (``benchmarks/realdata.py`` and ``rtlift data export`` read them from here).

Official rules (``data/README.md``): WH2009 ``full[5200:184000]``, estimation the first 100 000
samples, test the next 78 800, in mV; Silverbox test "arrow full" ``data[100:40575]``,
estimation the first 75 % of the multisine section ``data[40650:127400]``; Cascaded Tanks the
estimation and test records of 1024 samples each, in V. Every benchmark is scored by free-run
simulation from rest with the first ``STATE_INIT_SAMPLES`` test samples unscored.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rtlift.core.errors import UserError
from rtlift.core.records import SisoRecord, write_siso_record

DATA_DIR = Path(__file__).resolve().parents[2] / "data"
"""The repository's ``data/`` (a checkout or an editable install)."""
STATE_INIT_SAMPLES = 50
"""Test samples left unscored by every benchmark's rules (a state-initialisation window)."""


@dataclass(frozen=True)
class Benchmark:
    name: str
    file: str
    system: str
    unit: str        # the unit the published RMSEs are quoted in
    scale: float     # record units (V) → ``unit``


BENCHMARKS = {b.name: b for b in (
    Benchmark("wh2009", "wh2009.npz", "Wiener-Hammerstein electronic circuit (SYSID 2009), 51.2 kHz", "mV", 1e3),
    Benchmark("silverbox", "silverbox_SNLS80mV.npz", "Silverbox, an electronic Duffing oscillator, 610.35 Hz",
              "mV", 1e3),
    Benchmark("cascaded_tanks", "cascaded_tanks.npz", "two water tanks in cascade with overflow, Ts = 4 s",
              "V", 1.0),
)}


def _load(name: str, data_dir: str | os.PathLike | None) -> np.lib.npyio.NpzFile:
    if name not in BENCHMARKS:
        raise UserError(f"no benchmark {name!r}; the vendored ones are {', '.join(BENCHMARKS)}")
    path = Path(data_dir or DATA_DIR) / BENCHMARKS[name].file
    try:
        return np.load(path)
    except FileNotFoundError:
        raise UserError(f"{path}: not found (the benchmarks are vendored in a checkout's data/; "
                        "give the folder that holds them with --data)") from None


def splits(name: str, data_dir: str | os.PathLike | None = None
           ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, str]:
    """(fs, u_est, y_est, u_test, y_test, unit scale, unit) by the benchmark's official rules."""
    d = _load(name, data_dir)
    b = BENCHMARKS[name]
    if name == "wh2009":
        lo, hi = (int(v) for v in d["official_slice"])
        u, y, n = d["u"][lo:hi], d["y"][lo:hi], int(d["n_train"])
        return float(d["fs"]), u[:n], y[:n], u[n:], y[n:], b.scale, b.unit
    if name == "silverbox":
        u, y = d["V1"], d["V2"]
        ms_u, ms_y = u[40650:127400], y[40650:127400]
        n = int(round(0.75 * ms_u.size))
        return float(d["fs"]), ms_u[:n], ms_y[:n], u[100:40575], y[100:40575], b.scale, b.unit
    return 1.0 / float(d["Ts"]), d["u_est"], d["y_est"], d["u_test"], d["y_test"], b.scale, b.unit


def as_record(fs: float, u: np.ndarray, y: np.ndarray, name: str, **meta: str) -> SisoRecord:
    """A ``t,u,y`` record sampled at ``fs`` from t = 0."""
    return SisoRecord(np.arange(u.size) / fs, np.asarray(u, float), np.asarray(y, float),
                      {"fs_hz": repr(fs), **meta}, name)


def export(name: str, out: str | os.PathLike, data_dir: str | os.PathLike | None = None) -> list[Path]:
    """Write the official estimation and test splits of ``name`` as ``OUT/NAME_estimation.csv``
    and ``OUT/NAME_test.csv`` (``t,u,y`` records); the paths written."""
    fs, ue, ye, ut, yt, _, unit = splits(name, data_dir)
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{out}: cannot create the output folder ({exc.strerror})") from None
    written = []
    for split, u, y, note in (("estimation", ue, ye, "fit on it"),
                              ("test", ut, yt, f"free run from rest, the first {STATE_INIT_SAMPLES} samples "
                                               f"unscored (rtlift validate --skip {STATE_INIT_SAMPLES})")):
        path = out / f"{name}_{split}.csv"
        rec = as_record(fs, u, y, path.stem, benchmark=name, split=split, rmse_quoted_in=unit, scoring=note)
        try:
            write_siso_record(path, rec)
        except OSError as exc:
            raise UserError(f"{path}: cannot write ({exc.strerror})") from None
        written.append(path)
    return written
