"""The residual tests of rtlift.diagnose on a measured benchmark: Wiener–Hammerstein 2009.

A plain Wiener model (rtlift.identify.pem.fit_wiener, textbook form ŷ = Σ p_d y^d, y = G(q)u,
output-error PEM) misses the true system's output-side LTI block G2. We run the same residual
tests as ``rtlift diagnose`` on its residual (training and test parts of the official split):
the linear input cross-correlation and the Billings–Voon higher-order correlations (ε against
u², ŷ²), the spectrum, whiteness. Then the catalog's output-filter effect (``sensor_resonance``:
a unity-DC-gain second-order mode after the model) is fitted on the training part and judged
on the test part, and the test RMSE before/after is reported.

To stay well under two minutes the PEM uses the first ``N_EST`` = 30,000 of the 100,000
training samples (order 6, degree 5) and the correlation tests use every 4th residual sample of
the first 50,000 (subsampling said in the output). Test RMSE: free-run simulation over
[105200:184000] after the 50-sample state-initialisation window (mV), as the README defines.
Prints a summary and, as its last line, one JSON object.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy import optimize, signal

from rtlift.blocks.stages import resonance_ba
from rtlift.diagnose.residual import higher_order, input_crosscorr, spectrum, whiteness
from rtlift.identify.pem import fit_wiener

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
N_EST = 30_000
TEST_STRIDE = 4


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def tests(e: np.ndarray, u: np.ndarray, yhat: np.ndarray, fs: float) -> dict:
    s = slice(0, 50_000, TEST_STRIDE)
    es, us, ys = e[s], u[s], yhat[s]
    out = {"whiteness": whiteness(es, 40).to_dict(),
           "input_crosscorr": input_crosscorr(es, us, 40, label="u").to_dict()}
    for r in higher_order(es, us, ys, 40):
        out[r.name] = r.to_dict()
    sp = spectrum(e[:50_000], fs, min_hz=50.0)
    out["spectrum"] = sp.to_dict()
    return out


def main() -> int:
    path = DATA / "wiener_hammerstein_2009" / "wh2009.npz"
    if not path.is_file():
        print(f"benchmark data not found at {path}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    d = np.load(path)
    a, b = (int(v) for v in d["official_slice"])
    fs = float(d["fs"])
    u, y = d["u"][a:b], d["y"][a:b]
    n_train, skip = int(d["n_train"]), int(d["state_init_window"])
    ut, yt, uv, yv = u[:n_train], y[:n_train], u[n_train:], y[n_train:]
    res = fit_wiener(ut[:N_EST], yt[:N_EST], 6, form="output_poly", fs_hz=fs, degree=5, skip=100,
                     n_starts=1)
    ytr, _ = res.output(ut)
    yte, _ = res.output(uv)
    e_tr = yt - ytr
    before = {"train_rmse_mV": 1e3 * rmse(yt[skip:], ytr[skip:]), "test_rmse_mV": 1e3 * rmse(yv[skip:], yte[skip:])}
    residual = {"train": tests(e_tr, ut, ytr, fs), "test": tests(yv - yte, uv, yte, fs)}

    # candidate: an output-side mode after the Wiener model, fitted on training, judged on test
    def out_filter(theta: np.ndarray, x: np.ndarray) -> np.ndarray:
        bb, aa = resonance_ba(float(theta[0]), float(theta[1]), fs)
        return signal.lfilter(bb, aa, x)

    sl = slice(skip, N_EST)
    best = None
    for f0 in np.geomspace(500.0, 20_000.0, 12):
        for z0 in (0.1, 0.4, 0.8):
            c = rmse(yt[sl], out_filter(np.array([f0, z0]), ytr)[sl])
            if best is None or c < best[0]:
                best = (c, f0, z0)
    fit = optimize.least_squares(lambda th: yt[sl] - out_filter(th, ytr)[sl], [best[1], best[2]],
                                 bounds=([50.0, 0.01], [0.45 * fs, 2.0]), x_scale=[100.0, 0.05])
    after_test = 1e3 * rmse(yv[skip:], out_filter(fit.x, yte)[skip:])
    accepted = after_test < 0.985 * before["test_rmse_mV"]
    tr = residual["train"]
    result = {
        "benchmark": "wiener_hammerstein_2009",
        "subsampled": f"PEM on the first {N_EST} of {n_train} training samples; correlation tests on "
                      f"every {TEST_STRIDE}th of the first 50,000 residual samples",
        "plain_wiener": {"order": 6, "degree": 5, **before},
        "residual_tests": residual,
        "linear_vs_higher_order_train": {
            "max_r_u_e": tr["input_crosscorr"]["statistic"], "max_r_u2_e": tr["bv_u2_e"]["statistic"],
            "max_r_u2_e2": tr["bv_u2_e2"]["statistic"], "max_r_yhat2_e": tr["bv_y2_e"]["statistic"],
            "bound": tr["input_crosscorr"]["threshold"]},
        "augmentation": {"name": "sensor_resonance (output-side second-order block)",
                         "params": {"frequency_hz": float(fit.x[0]), "damping_ratio": float(fit.x[1])},
                         "accepted": bool(accepted),
                         "test_rmse_before_mV": before["test_rmse_mV"], "test_rmse_after_mV": after_test},
        "seconds": round(time.perf_counter() - t0, 1),
    }
    lv = result["linear_vs_higher_order_train"]
    print(f"plain Wiener (order 6, degree 5): test RMSE {before['test_rmse_mV']:.2f} mV "
          f"(train {before['train_rmse_mV']:.2f} mV)")
    print(f"residual vs past input   max |r_ue|     = {lv['max_r_u_e']:.3f} (bound {lv['bound']:.3f})")
    print(f"Billings-Voon            max |r_u2'e|   = {lv['max_r_u2_e']:.3f}, max |r_u2'e2'| = "
          f"{lv['max_r_u2_e2']:.3f}, max |r_yhat2'e| = {lv['max_r_yhat2_e']:.3f}")
    print(f"whiteness: {tr['whiteness']['detail']}")
    print(f"spectrum: {tr['spectrum']['detail']}")
    aug = result["augmentation"]
    print(f"output-side mode f0 = {fit.x[0]:.0f} Hz, zeta = {fit.x[1]:.2f}: test RMSE "
          f"{aug['test_rmse_before_mV']:.2f} -> {aug['test_rmse_after_mV']:.2f} mV "
          f"({'accepted' if accepted else 'not accepted'})")
    print(json.dumps(result, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
