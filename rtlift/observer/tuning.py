"""Q and R from data: the measurement noise from the actuator-off seconds (:func:`fit_noise`,
white + AR by Whittle likelihood), the process noise by maximum likelihood of the observer's
innovations (:func:`tune_observer`). What ``rtlift identify`` stores in the model file's
``observer`` section."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from rtlift.core.records import Record
from rtlift.model.hybrid import HybridModel
from rtlift.observer.config import ObserverConfig
from rtlift.observer.filter import Observer
from rtlift.observer.layout import StateLayout


def actuator_off_noise(record: Record, tare_seconds: float = 2.0) -> np.ndarray:
    """ΔCL over the first ``tare_seconds`` while the actuator is off (mean removed)."""
    n = int(round(tare_seconds * record.fs_hz))
    off = (record.cmu[:n] == 0) & (record.cmu_envelope[:n] == 0)
    z = record.dcl[:n][off]
    return z - z.mean() if z.size else z


def _open_loop(model: HybridModel, rec: Record) -> dict[str, np.ndarray]:
    """Per sample, by the model's own batch twins from rest: ``u`` = Cμ_env′ (after the input
    stages), the Wiener gain N(u) (``gain``, input-gain form only) and the open-loop model."""
    m = model.copy()
    cmu, env = m.inputs_simulate(rec.cmu, rec.cmu_envelope)
    total = sum(m.parts_simulate(cmu, env))
    for s in m.output_stages:
        total = s.simulate(total)
    u = np.asarray(env, dtype=float)
    nl = model.copy().wiener.nonlinearity
    gains = nl.simulate(u, np.ones_like(u)) if StateLayout(m).form == "input_gain" else None
    return {"u": u, "gain": gains, "model": total}


def fit_noise(segments: Sequence[np.ndarray], order: int = 2) -> dict[str, Any]:
    """White + AR(``order``) model of the actuator-off noise, by Whittle likelihood on the pooled
    periodograms of the segments (each mean-removed, ≥ 64 samples)::

        z(k) = e(k) + v(k),   e(k) = Σ a_i e(k−i) + w(k),   v ~ N(0, R_w),   w ~ N(0, q)
        S(ω) = R_w + q / |1 − Σ a_i e^{−jωi}|²

    The AR poles are parametrised as a complex pair (radius, angle) for order 2, real radii
    otherwise, radius ≤ 0.995 (a slower part is drift, the bias state's). Returns ``R`` (= R_w),
    ``noise_ar``, ``q_noise`` and ``total`` (variance of the segments); white only (R = total)
    unless the coloured model wins the likelihood-ratio test against white noise at 0.1 %."""
    from scipy import optimize
    from scipy.stats import chi2

    R_MAX = 0.995  # noqa: N806

    segs = [np.asarray(z, float) - np.mean(z) for z in segments if len(z) >= 64]
    if not segs:
        raise ValueError("fit_noise needs a segment of at least 64 samples")
    total = float(np.mean(np.concatenate(segs) ** 2))
    pgrams = []
    for z in segs:
        Z = np.fft.rfft(z)
        w = 2.0 * np.pi * np.arange(Z.size) / z.size
        pgrams.append((w[1:-1], np.abs(Z[1:-1]) ** 2 / z.size))

    def coeffs(p: np.ndarray) -> np.ndarray:
        if order == 2:     # a complex or double pole pair: radius, angle
            r = _logistic(R_MAX, p[2])
            th = _logistic(math.pi, p[3])
            return np.array([2.0 * r * math.cos(th), -r * r])
        x = p[2:2 + order]
        radii = R_MAX / (1.0 + np.exp(-x)) if np.all(x > -EXP_ARG_MAX) else [_logistic(R_MAX, v) for v in x]
        return -np.poly(radii)[1:]

    def nll(p: np.ndarray) -> float:
        if max(p[0], p[1]) > EXP_ARG_MAX:     # the simplex wandered off: variances past any data
            return math.inf
        a = coeffs(p)
        out = 0.0
        for w, per in pgrams:
            den = np.abs(1.0 - sum(a[i] * np.exp(-1j * (i + 1) * w) for i in range(order))) ** 2
            spec = math.exp(p[0]) + math.exp(p[1]) / den
            out += float(np.sum(np.log(spec) + per / spec))
        return out

    best = None
    for frac in (0.01, 0.1, 0.5):
        for th in (-3.0, -1.5, 0.0, 1.5):
            shape = [2.0, th] if order == 2 else [2.0 + th] * order
            p0 = np.array([math.log(total * (1 - frac)), math.log(total * frac * 0.05), *shape])
            res = optimize.minimize(nll, p0, method="Nelder-Mead",
                                    options={"maxiter": 3000, "xatol": 1e-5, "fatol": 1e-7})
            if best is None or res.fun < best.fun:
                best = res
    white = sum(float(np.sum(np.log(total) + per / total)) for _, per in pgrams)
    if 2.0 * (white - best.fun) < chi2.ppf(0.999, order + 1):       # likelihood ratio: no colour
        return {"R": total, "noise_ar": (), "q_noise": 0.0, "total": total}
    a = coeffs(best.x)
    Rw, q = math.exp(best.x[0]), math.exp(best.x[1])
    Fn = np.zeros((order, order))
    Fn[0, :] = a
    Fn[1:, :-1] = np.eye(order - 1)
    e1 = np.zeros((order, order))
    e1[0, 0] = 1.0
    ar_var = float(solve_discrete_lyapunov(Fn, e1)[0, 0]) * q
    return {"R": Rw, "noise_ar": tuple(float(v) for v in a), "q_noise": q, "total": total,
            "coloured_std": math.sqrt(ar_var)}


EXP_ARG_MAX = 700.0
"""``math.exp`` overflows past 709.78: :func:`fit_noise`'s likelihood is +∞ where a log-variance passes
this, and :func:`_logistic` changes its form below −this."""


def _logistic(scale: float, x: float) -> float:
    """scale/(1 + e^{−x}) for any finite x, without overflow: e^{−x} for x ≪ 0 overflowed in
    :func:`fit_noise`'s simplex on plant draw 125's campaign, an internal error of ``rtlift identify``.
    Above −:data:`EXP_ARG_MAX` it is the expression as it always was, the same bits."""
    if x > -EXP_ARG_MAX:
        return scale / (1.0 + math.exp(-x))
    e = math.exp(x)
    return scale * e / (1.0 + e)


HARMONICS = (8, 12)
"""Numbers of burst-synchronous ripple harmonics :func:`tune_observer` tries by default."""


def tune_observer(model: HybridModel, records: Sequence[Record], *, tare_seconds: float = 2.0,
                  max_seconds: float = 30.0, skip_seconds: float = 2.0,
                  gate_probability: float = 0.9999, max_rejections: int = 10,
                  harmonics: int | Sequence[int] = HARMONICS, ripple_powers: int = 1,
                  sweeps: int = 1) -> dict[str, Any]:
    """Q and R from data, for ``save_model(..., observer=tune_observer(model, records))``.

    - Noise: the actuator-off tare seconds at the start of each record (pooled) give R and the
      coloured part of the noise (buffeting: :func:`fit_noise`); if no record has them, R is
      half the variance of the first difference of the open-loop residual (white only).
    - Structure: ``harmonics`` burst-synchronous ripple harmonics (0: none) and a random-walk
      gain on ΔCL_H (module docstring). Given several numbers of harmonics, each is tuned and
      the one with the highest innovation likelihood is kept (``harmonics_nll`` lists them): the
      better the model's own ripple, the more of the measured ripple's finer shape the states
      must carry for the estimate to follow the lift rather than the buffeting beside it.
    - Q: ``q_x``, ``q_bias``, ``q_ripple``, ``q_gain_h`` and a common scale of the noise
      (R and q_noise together: the tare is taken stalled, where buffeting is strongest) by
      maximum likelihood of the innovations (:attr:`Observer.nll`), coordinate search on a
      log grid (factors 10 then √10, ``sweeps`` passes), starting from values relative to R.
      The consistency that results (mean NIS, fraction in the χ²₁ band) is reported.
    At most ``max_seconds`` of each record are used; the first ``skip_seconds`` are not scored.
    """
    if not records:
        raise ValueError("tune_observer needs at least one record")
    if not isinstance(harmonics, int):
        tuned = {h: tune_observer(model, records, tare_seconds=tare_seconds, max_seconds=max_seconds,
                                  skip_seconds=skip_seconds, gate_probability=gate_probability,
                                  max_rejections=max_rejections, harmonics=int(h), ripple_powers=ripple_powers,
                                  sweeps=sweeps) for h in harmonics}
        best = min(tuned, key=lambda h: tuned[h]["nll"])
        return {**tuned[best], "harmonics_nll": {str(h): tuned[h]["nll"] for h in tuned}}
    fs = model.fs_hz
    recs = [r.slice(0, int(round(max_seconds * fs))) for r in records]
    quiet = [actuator_off_noise(r, tare_seconds) for r in recs]
    pooled = np.concatenate(quiet)
    if pooled.size >= 200:
        noise = fit_noise(quiet)
        r_source = (f"actuator-off tare ({pooled.size} samples in the first {tare_seconds:g} s): "
                    + ("white + AR(2) by Whittle likelihood" if noise["noise_ar"] else "white"))
    else:
        res = np.concatenate([r.dcl - _open_loop(model, r)["model"] for r in recs])
        R = float(np.var(np.diff(res)) / 2.0)
        noise = {"R": R, "noise_ar": (), "q_noise": 0.0, "total": R}
        r_source = "half the variance of the first difference of the open-loop residual"
    if not noise["R"] > 0:
        raise ValueError("measurement noise variance is zero: cannot tune the observer")
    R_total = noise["total"]
    data = [_open_loop(model, r) for r in recs]
    u = np.concatenate([d["u"] for d in data])
    layout = StateLayout(model)
    nl = model.wiener.nonlinearity
    if layout.form == "input_gain":
        g_ref = float(np.mean(np.abs(np.concatenate([d["gain"] for d in data])))) or 1.0
    else:
        g_ref = float(np.mean(np.abs(np.diff(nl.f) / np.diff(nl.y)))) or 1.0
    env2 = float(np.mean(u[u > 0] ** 2)) if np.any(u > 0) else 1.0
    p0_ripple = R_total / env2
    skip = int(round(skip_seconds * fs))
    arrays = [(r.cmu.tolist(), r.cmu_envelope.tolist(), [None if z != z else z for z in r.dcl.tolist()])
              for r in recs]

    def config(p: dict[str, float]) -> ObserverConfig:
        ns = 10.0 ** p["noise"]
        return ObserverConfig(R=noise["R"] * ns, q_x=10.0 ** p["q_x"] * R_total / g_ref**2,
                              q_bias=10.0 ** p["q_bias"] * R_total, p0_bias=R_total,
                              gate_probability=gate_probability, max_rejections=max_rejections,
                              noise_ar=noise["noise_ar"], q_noise=noise["q_noise"] * ns,
                              ripple_harmonics=harmonics, ripple_powers=ripple_powers,
                              q_ripple=10.0 ** p["q_ripple"] * p0_ripple if harmonics else 0.0,
                              p0_ripple=p0_ripple if harmonics else 0.0,
                              q_gain_h=10.0 ** p["q_gain_h"])

    cache: dict[tuple, dict[str, float]] = {}

    def score(p: dict[str, float]) -> dict[str, float]:
        key = tuple(round(p[k], 6) for k in sorted(p))
        if key not in cache:
            obs = Observer(model, config(p))
            nll = nis = band = 0.0
            updates = rejected = 0
            for c, e, z in arrays:
                obs.reset()
                step = obs.step
                n_skip = min(skip, len(c) // 4)
                for k in range(n_skip):
                    step(c[k], e[k], z[k])
                obs.clear_monitors()
                for k in range(n_skip, len(c)):
                    step(c[k], e[k], z[k])
                if obs.updates:
                    nll += obs.nll * obs.updates
                    nis += obs.nis_mean * obs.updates
                    band += obs.nis_band_fraction * obs.updates
                updates += obs.updates
                rejected += obs.rejected
            cache[key] = {"nll": nll / max(updates, 1), "nis_mean": nis / max(updates, 1),
                          "nis_band_fraction": band / max(updates, 1), "rejected": rejected}
        return cache[key]

    # log10 of: noise scale, q_x·g²/R, q_bias/R, q_ripple/p0_ripple, q_gain_h; start and bounds
    p = {"noise": 0.0, "q_x": -3.0, "q_bias": -4.0, "q_ripple": -4.0, "q_gain_h": -5.0}
    bounds = {"noise": (-1.0, 1.0), "q_x": (-6.0, 0.0), "q_bias": (-6.0, -2.0), "q_ripple": (-8.0, -1.0),
              "q_gain_h": (-8.0, -2.0)}
    names = ["noise", "q_x", "q_bias", "q_gain_h"] + (["q_ripple"] if harmonics else [])
    for step_size in [1.0] * sweeps + [0.5] * sweeps:
        for name in names:
            best = score(p)["nll"]
            for sign in (-1.0, 1.0):
                while True:
                    trial = dict(p, **{name: p[name] + sign * step_size})
                    if not bounds[name][0] <= trial[name] <= bounds[name][1]:
                        break
                    s = score(trial)["nll"]
                    if not s < best:
                        break
                    best, p = s, trial
    best_cfg = config(p)
    result = score(p)
    out = best_cfg.to_dict()
    out.update({
        "method": "R and a coloured (AR) noise part from actuator-off noise (Whittle); q_x, q_bias, "
                  "q_ripple, q_gain_h and a common noise scale by innovation maximum likelihood "
                  "(coordinate search on a log grid)",
        "r_source": r_source,
        "tuned_on": [r.name for r in records],
        "nis_mean": float(result["nis_mean"]),
        "nis_band_fraction": float(result["nis_band_fraction"]),
        "rejected": int(result["rejected"]),
        "nll": float(result["nll"]),
        "evaluations": len(cache),
        "measurement_noise_std": math.sqrt(R_total),
        "log10_factors": {k: round(v, 3) for k, v in p.items()},
    })
    return out
