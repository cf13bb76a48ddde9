"""The lift identification's Wiener input, recorded against delivered (issue 47, fifth pass).

For each plant draw (``--draws 0-3``: our bench and calibration draws 1–3; never a reporting
draw for a choice) the clean campaign is recorded once (``rtlift bench record``: static,
single_burst, sine_k0125, and ``random`` as a held-out record) into ``DIR/records``, and the
model is identified twice by ``rtlift identify`` (the same three records): with the envelope as
recorded (``DIR/recorded/N_model.json``, the convention before this pass) and with the
``onset_hold`` stage's delivered envelope (``DIR/delivered/N_model.json``; ``IdentifyOptions.envelope``,
which ``rtlift identify`` has no flag for: set here for the run).
For each model the held-out errors:

- the identification's own: RMSE on the training record's last 30 % (held out of the fit);
- on the draw's ``random`` record (never in the fit): RMSE of ΔCL − the model's ΔCL after 0.5 s,
  and the relative error |Σ e ŷ*| / Σ |ŷ|² of the error against the prediction (cross-spectrum,
  Welch, 4 s segments) in 0.05–0.7 Hz (the loop's band), as the fourth pass measured it.

Then ``benchmarks/model_error.py --keep DIR/recorded`` and ``--keep DIR/delivered`` compare each
model's lifted plant with the truth's. Prints a table, then one JSON line.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, run_cli  # noqa: E402

EXPERIMENTS = ("static", "single_burst", "sine_k0125", "random")
BAND_HZ = (0.05, 0.7)


def records(n: int, folder: str) -> dict[str, str]:
    """The draw's campaign records (recorded once, reused)."""
    os.makedirs(folder, exist_ok=True)
    files = {}
    for exp in EXPERIMENTS:
        files[exp] = os.path.join(folder, f"{n}_{exp}.csv")
        if not os.path.exists(files[exp]):
            run_cli("bench", "record", "--plant-draw", n, "--out", files[exp], exp)
    return files


def identify(files: dict[str, str], path: str, envelope: str) -> None:
    """``rtlift identify`` on the three records into ``path``, with the Wiener input ``envelope``
    (the CLI's options with ``IdentifyOptions.envelope`` set: it has no flag for it)."""
    import rtlift.identify.campaign as campaign

    original = campaign.IdentifyOptions
    campaign.IdentifyOptions = functools.partial(original, envelope=envelope)
    try:
        run_cli("identify", "--static", files["static"], "--single-burst", files["single_burst"], "--train",
                files["sine_k0125"], "-o", path, "--quiet")
    finally:
        campaign.IdentifyOptions = original


def held_out(path: str, files: dict[str, str]) -> dict:
    """The model's held-out errors (module docstring)."""
    import json

    from scipy import signal

    from rtlift.core.records import read_record
    from rtlift.model.modelfile import load_model

    doc = json.load(open(path, encoding="utf-8"))
    model = load_model(path)
    rec = read_record(files["random"])
    fs = model.fs_hz
    y = model.simulate(rec.cmu, rec.cmu_envelope).total
    skip = int(0.5 * fs)
    e, yh = rec.dcl[skip:] - y[skip:], y[skip:] - np.mean(y[skip:])
    f, pey = signal.csd(e, yh, fs=fs, nperseg=int(4 * fs))
    _, pyy = signal.welch(yh, fs=fs, nperseg=int(4 * fs))
    band = (f >= BAND_HZ[0]) & (f <= BAND_HZ[1])
    rel = np.abs(pey[band]) / pyy[band]
    metrics = doc.get("metrics") or doc.get("provenance", {}).get("metrics", {})
    return {"train_holdout_rmse": metrics.get("holdout", {}).get("rmse", float("nan")),
            "random_rmse": float(np.sqrt(np.mean(e ** 2))),
            "random_rel_err_max_band": float(rel.max()), "random_rel_err_mean_band": float(rel.mean()),
            "stages": [s["name"] for s in doc["input_stages"]]}


def main() -> None:
    from benchmarks.control_family import draws as parse_draws

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", default="0-3", help="plant draws, A-B or A,B (default 0-3)")
    ap.add_argument("--dir", required=True, help="records and both models are kept here (reused)")
    ap.add_argument("--envelope", choices=("recorded", "delivered", "both"), default="both")
    args = ap.parse_args()
    conventions = ("recorded", "delivered") if args.envelope == "both" else (args.envelope,)
    out = []
    for n in parse_draws(args.draws):
        files = records(n, os.path.join(args.dir, "records"))
        row = {"draw": n}
        for conv in conventions:
            folder = os.path.join(args.dir, conv)
            os.makedirs(folder, exist_ok=True)
            path = os.path.join(folder, f"{n}_model.json")
            t0 = time.process_time()
            if not os.path.exists(path):
                identify(files, path, conv)
            row[conv] = {"identify_cpu_s": time.process_time() - t0, **held_out(path, files)}
            h = row[conv]
            print(f"draw {n} {conv:9s}: train held-out RMSE {h['train_holdout_rmse']:.5f}, random RMSE "
                  f"{h['random_rmse']:.5f}, |e/y| in {BAND_HZ[0]}-{BAND_HZ[1]} Hz "
                  f"max {100 * h['random_rel_err_max_band']:.2f} % mean {100 * h['random_rel_err_mean_band']:.2f} % "
                  f"({h['identify_cpu_s']:.0f} s CPU)", flush=True)
        out.append(row)
    emit({"draws": out})


if __name__ == "__main__":
    main()
