"""The measured nonlinear benchmarks vendored in the package's ``rtlift/data/benchmarks/`` (its
``README.md``: provenance, licences, checksums; installed with the package, so found from any install)
and their official splits: the one place that knows how each ``.npz`` is cut into estimation and
test data (``benchmarks/realdata.py`` and ``rtlift data export`` read them from here).

Official rules (that ``README.md``): WH2009 ``full[5200:184000]``, estimation the first 100 000
samples, test the next 78 800, in mV; Silverbox test "arrow full" ``data[100:40575]``,
estimation the first 75 % of the multisine section ``data[40650:127400]``; Cascaded Tanks the
estimation and test records of 1024 samples each, in V; Silverbox's Schroeder test the one
Schroeder-phase multisine period of ``Schroeder80mV`` (1024 samples from 0-based sample 10584,
after the 50 samples before it), estimation as Silverbox's; Silverbox's multisine test the last 25 % of the
multisine section (``data[40650:127400][65062:]``, 21 688 samples; the official split's ``test_multisine``,
the published DT SUBNET 0.36 mV is on it), estimation as Silverbox's; WH with process noise the 10
estimation-example and 2 fade-out runs (8192 samples each, each its own run) for estimation, the
random-phase multisine and the sine sweep of the test set (16384 each), in mV. Every benchmark is
scored by free-run simulation from rest with the first ``STATE_INIT_SAMPLES`` test samples unscored.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rtlift.core.errors import UserError
from rtlift.core.records import SisoRecord, write_siso_record

DATA_DIR = Path(__file__).resolve().parents[1] / "data" / "benchmarks"
"""``rtlift/data/benchmarks/``: package data, there in a checkout and in every install."""
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
    Benchmark("silverbox_schroeder", "silverbox_schroeder.npz",
              "Silverbox, tested on its Schroeder-phase multisine period (estimation as silverbox)", "mV", 1e3),
    Benchmark("silverbox_multisine", "silverbox_SNLS80mV.npz",
              "Silverbox, tested on the last 25 % of its multisine section (estimation as silverbox)", "mV", 1e3),
    Benchmark("wh_process_noise", "wh_process_noise.npz",
              "Wiener-Hammerstein circuit with process noise (2017), 78.125 kHz, 12 runs", "mV", 1e3),
)}
"""The vendored benchmarks; the first three were looked at while the structures were grown, the
rest (issue 48) were not (``silverbox_multisine`` added in its fourth pass, first scored then)."""


def _load(name: str, data_dir: str | os.PathLike | None) -> np.lib.npyio.NpzFile:
    if name not in BENCHMARKS:
        raise UserError(f"no benchmark {name!r}; the vendored ones are {', '.join(BENCHMARKS)}")
    path = Path(data_dir or DATA_DIR) / BENCHMARKS[name].file
    try:
        return np.load(path)
    except FileNotFoundError:
        raise UserError(f"{path}: not found (give the folder that holds the .npz files with --data, or leave "
                        "--data out for the ones installed with rtlift)") from None


Parts = list[tuple[str, np.ndarray, np.ndarray]]
"""Named (u, y) runs, each its own experiment from rest."""


def estimation(name: str, data_dir: str | os.PathLike | None = None) -> tuple[float, Parts]:
    """(fs, the official estimation runs) — read without the test data (``benchmarks/realdata.py``
    freezes every choice on these before :func:`tests` is called)."""
    if name in ("silverbox_schroeder", "silverbox_multisine"):
        return estimation("silverbox", data_dir)
    d = _load(name, data_dir)
    if name == "wh2009":
        lo, hi = (int(v) for v in d["official_slice"])
        n = int(d["n_train"])
        return float(d["fs"]), [("estimation", d["u"][lo:lo + n], d["y"][lo:lo + n])]
    if name == "silverbox":
        ms_u, ms_y = d["V1"][40650:127400], d["V2"][40650:127400]
        n = int(round(0.75 * ms_u.size))
        return float(d["fs"]), [("estimation", ms_u[:n], ms_y[:n])]
    if name == "wh_process_noise":
        runs = [(f"estimation_{k}", d["u_est"][:, k], d["y_est"][:, k]) for k in range(d["u_est"].shape[1])]
        runs += [(f"estimation_fadeout_{k}", d["u_fadeout"][:, k], d["y_fadeout"][:, k])
                 for k in range(d["u_fadeout"].shape[1])]
        return float(d["fs"]), runs
    return 1.0 / float(d["Ts"]), [("estimation", d["u_est"], d["y_est"])]


def tests(name: str, data_dir: str | os.PathLike | None = None) -> Parts:
    """The official test records (each scored by free run from rest, the first
    :data:`STATE_INIT_SAMPLES` unscored)."""
    d = _load(name, data_dir)
    if name == "wh2009":
        lo, hi = (int(v) for v in d["official_slice"])
        n = int(d["n_train"])
        return [("test", d["u"][lo + n:hi], d["y"][lo + n:hi])]
    if name == "silverbox":
        return [("test", d["V1"][100:40575], d["V2"][100:40575])]
    if name == "silverbox_schroeder":
        return [("test", d["V1"], d["V2"])]
    if name == "silverbox_multisine":
        ms_u, ms_y = d["V1"][40650:127400], d["V2"][40650:127400]
        n = int(round(0.75 * ms_u.size))
        return [("test", ms_u[n:], ms_y[n:])]
    if name == "wh_process_noise":
        return [(f"test_{kind}", d["u_test"][:, k], d["y_test"][:, k]) for k, kind in enumerate(("multisine", "sweep"))]
    return [("test", d["u_test"], d["y_test"])]


def splits(name: str, data_dir: str | os.PathLike | None = None
           ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, str]:
    """(fs, u_est, y_est, u_test, y_test, unit scale, unit) of a benchmark with one estimation run
    and one test record, by its official rules."""
    fs, est = estimation(name, data_dir)
    test = tests(name, data_dir)
    if len(est) != 1 or len(test) != 1:
        raise ValueError(f"{name} has {len(est)} estimation runs and {len(test)} test records")
    b = BENCHMARKS[name]
    return fs, est[0][1], est[0][2], test[0][1], test[0][2], b.scale, b.unit


def as_record(fs: float, u: np.ndarray, y: np.ndarray, name: str, **meta: str) -> SisoRecord:
    """A ``t,u,y`` record sampled at ``fs`` from t = 0."""
    return SisoRecord(np.arange(u.size) / fs, np.asarray(u, float), np.asarray(y, float),
                      {"fs_hz": repr(fs), **meta}, name)


def export(name: str, out: str | os.PathLike, data_dir: str | os.PathLike | None = None) -> list[Path]:
    """Write the official estimation runs and test records of ``name`` as ``OUT/NAME_<part>.csv``
    (``t,u,y`` records: ``NAME_estimation.csv`` and ``NAME_test.csv`` for a benchmark with one of
    each); the paths written."""
    fs, est = estimation(name, data_dir)
    test = tests(name, data_dir)
    unit = BENCHMARKS[name].unit
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{out}: cannot create the output folder ({exc.strerror})") from None
    written = []
    scoring = (f"free run from rest, the first {STATE_INIT_SAMPLES} samples unscored "
               f"(rtlift validate --skip {STATE_INIT_SAMPLES})")
    for part, u, y, note in [(p, u, y, "fit on it") for p, u, y in est] + [(p, u, y, scoring) for p, u, y in test]:
        path = out / f"{name}_{part}.csv"
        rec = as_record(fs, u, y, path.stem, benchmark=name, split=part, rmse_quoted_in=unit, scoring=note)
        try:
            write_siso_record(path, rec)
        except OSError as exc:
            raise UserError(f"{path}: cannot write ({exc.strerror})") from None
        written.append(path)
    return written
