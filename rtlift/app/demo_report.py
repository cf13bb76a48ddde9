"""The demo's reporting (:mod:`rtlift.app.demo` runs it): figures of the live observer and the
closed loop, the plain-text results table, ``report.md``."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from rtlift.core.rate import FS_HZ

__all__ = ["live_report", "report_markdown", "results_table", "tracking_figure"]


def tracking_figure(t: np.ndarray, ref: np.ndarray, traces: dict, rows: dict, path: str) -> None:
    """The closed-loop section's figure: the bench's truth of both runs (``traces``: feedback
    ``"off"``/``"on"`` → t, truth, envelope V) against the reference."""
    from rtlift.app.figures import control_figure

    style = {"off": ("tab:orange", "feedforward only"), "on": ("tab:blue", "feedforward + feedback")}
    runs = [(f"{label}: bench truth (RMSE {rows[fb]['rmse_truth']:.4f})", color, tt, truth, tt, env)
            for fb, (tt, truth, env) in traces.items() for color, label in [style[fb]]]
    control_figure(t, ref, runs, path, "closed loop on the bench: undeclared actuator fade to 75 %", FS_HZ,
                   xlabel="t from the start of tracking (s)")


def live_report(cols: np.ndarray, true: np.ndarray, counters: dict[str, int], p50: float | None,
                 p99: float | None, step_us: np.ndarray, out: str, skip: int) -> dict[str, Any]:
    """RMSE of measurement, open-loop model and observer against the bench's truth from sample
    ``skip`` on; a figure."""
    from rtlift.app.figures import observer_figure
    from rtlift.core.metrics import rmse

    ok = ~np.isnan(cols[:, 0])
    ok[:skip] = False
    meas, hat, model = cols[ok, 0], cols[ok, 1], cols[ok, 2]
    tru = true[ok]
    result = {
        "seconds": len(cols) / FS_HZ,
        "scored_from_s": skip / FS_HZ,
        "link": counters,
        "rmse_vs_truth": {"measurement": rmse(tru, meas), "open_loop_model": rmse(tru, model),
                          "observer": rmse(tru, hat)},
        "latency_p50_ms": p50, "latency_p99_ms": p99,
        "observer_step_median_us": float(np.median(step_us)) if step_us.size else None,
        "observer_step_p99_us": float(np.percentile(step_us, 99)) if step_us.size else None,
        "figure": "figures/live_observer.png",
    }
    r = result["rmse_vs_truth"]
    observer_figure(np.arange(len(cols)) / FS_HZ, cols[:, 0], cols[:, 1], cols[:, 2],
                    os.path.join(out, "figures", "live_observer.png"),
                    f"observer live at 400 Hz over a serial pty — RMSE vs truth: measured {r['measurement']:.4f}, "
                    f"open loop {r['open_loop_model']:.4f}, observer {r['observer']:.4f}", FS_HZ, truth=true)
    return result


def _fmt(v: Any, spec: str = ".4f") -> str:
    return "–" if v is None else format(v, spec)


def _params(params: dict[str, Any], sep: str) -> str:
    """An effect's parameters as ``k<sep>v, ...``, each value as the diagnosis report writes it
    (numbers to 4 digits; strings, lists and mappings too: an output nonlinearity's ``form``)."""
    from rtlift.diagnose.report import param_text

    return ", ".join(f"{k}{sep}{param_text(v)}" for k, v in params.items())


def results_table(summary: dict[str, Any]) -> str:
    """The short table printed at the end of the demo (plain text)."""
    v = summary["validation"]
    lines = ["paper protocol (identified on sine_k0125), correlation coefficient ρ",
             f"  {'record':<12} {'paper':>7} {'rtlift':>7} {'conv only':>10} {'Wiener only':>12} {'NRMSE':>7}"]
    for name in ("sine_k0125", "sine_k025", "random"):
        row = v[name]
        lines.append(f"  {name:<12} {_fmt(row['paper_corr']):>7} {_fmt(row['hybrid']['corr']):>7} "
                     f"{_fmt(row['convolution_only']['corr']):>10} {_fmt(row['wiener_only']['corr']):>12} "
                     f"{_fmt(row['hybrid']['nrmse'], '.3f'):>7}")
    live = summary["live"]
    r = live["rmse_vs_truth"]
    lines += ["", f"observer live {live['seconds']:g} s at 400 Hz, RMSE vs bench truth: measured "
                  f"{r['measurement']:.4f}, open-loop model {r['open_loop_model']:.4f}, observer {r['observer']:.4f}",
              f"  lost samples {live['link']['lost']}, receive->estimate latency p50 "
              f"{_fmt(live['latency_p50_ms'], '.3f')} ms, p99 {_fmt(live['latency_p99_ms'], '.3f')} ms, "
              f"observer step p99 {_fmt(live['observer_step_p99_us'], '.1f')} us"]
    d = summary["diagnosis"]
    found = ", ".join(f"{e['name']} ({_params(e['params'], '=')})" for e in d["accepted"]) or "nothing"
    lines += ["", f"undeclared effect injected: {d['injected']}", f"  diagnosis found: {found}"]
    for name, e in d["records"].items():
        lines.append(f"  {name:<20} RMSE {e['rmse_before']:.5f} -> {e['rmse_after']:.5f}")
    c = summary["closed_loop"]
    lines += ["", f"closed loop {c['seconds']:g} s (steps, then a slow sine) under an undeclared actuator fade to 75 %,"
                  " RMSE of the bench truth vs the reference (1 Hz low-pass)"]
    for label, key in (("feedforward only", "feedforward"), ("ff + feedback", "feedback")):
        r = c[key]
        lines.append(f"  {label:<17} RMSE {r['rmse_truth']:.4f}  lost {r['lost']}  commands sent "
                     f"{r['commands_sent']} applied {r['commands_applied']} superseded {r['superseded']}  "
                     f"latency p99 {_fmt(r['command_latency_p99_ms'], '.2f')} ms")
    lines.append(f"  feedback / feedforward RMSE {c['ratio']:.2f}")
    lines += [f"  the feedback design misses a target: {w}" for w in c.get("design_warnings", [])]
    lines += [f"  caution on the feedback design: {w}" for w in c.get("design_cautions", [])]
    return "\n".join(lines)


def report_markdown(summary: dict[str, Any]) -> str:
    """``report.md``: every stage of the demo, with its figures."""
    v, live, d, idn = summary["validation"], summary["live"], summary["diagnosis"], summary["identify"]
    c = summary["campaign"]
    md = ["# rtlift demo report", "",
          "Everything below was measured in this run on the simulated bench (seed "
          f"{summary['seed']}); `summary.json` holds the same numbers.", "",
          "## 1. The standard campaign, recorded through the serial link", "",
          f"{len(c['records'])} experiments, {c['seconds']:.0f} s of 400 Hz data, recorded as `rtlift record` "
          "records a rig: the host commands each program (envelope, burst period) over protocol version 2 to the "
          "emulated DAQ on a pseudo-terminal, and `firmware_io` decodes what it streams (COBS + CRC-16).", "",
          "| received | lost | bad frames | duplicates | resyncs | events | commands sent | commands applied |",
          "|---|---|---|---|---|---|---|---|",
          "| {received} | {lost} | {crc_errors} | {duplicates} | {resyncs} | {events} | {commands_sent} | "
          "{commands_applied} |".format(**c["link"]), "",
          "## 2. Identification", "",
          f"Identified in {idn['seconds']:.1f} s: high-pass filter order {idn['highpass']['order']} at "
          f"{idn['highpass']['cutoff_hz']:g} Hz (chosen by held-out error), Wiener LTI order "
          f"{idn['wiener_order']} by output-error PEM; model file `model.json`.", "",
          "## 3. Validation (the paper's protocol: identify on sine_k0125)", "",
          "| record | paper ρ | rtlift ρ | NRMSE | RMSE | convolution only ρ (NRMSE) | Wiener only ρ (NRMSE) |",
          "|---|---|---|---|---|---|---|"]
    for name, row in v.items():
        h, cv, w = row["hybrid"], row["convolution_only"], row["wiener_only"]
        md.append(f"| {name} | {_fmt(row['paper_corr'])} | {h['corr']:.4f} | {h['nrmse']:.3f} | {h['rmse']:.4f} | "
                  f"{cv['corr']:.4f} ({cv['nrmse']:.2f}) | {w['corr']:.4f} ({w['nrmse']:.2f}) |")
    md += ["", "ρ alone flatters the convolution model: it tracks the shape but over-predicts the slow lift "
           "(see its NRMSE).", ""]
    md += [f"![{name}](figures/validate_{name}.png)" for name in v]
    r = live["rmse_vs_truth"]
    md += ["", f"## 4. The Kalman observer live at 400 Hz ({live['seconds']:g} s)", "",
           f"Scored from t = {live['scored_from_s']:g} s (the settle and the tare with the actuator off, then "
           "one second of the program for the observer to settle).", "",
           "| | RMSE vs the bench's noise-free ΔCL |", "|---|---|",
           f"| raw measurement | {r['measurement']:.5f} |", f"| open-loop hybrid model | {r['open_loop_model']:.5f} |",
           f"| Kalman observer | {r['observer']:.5f} |", "",
           f"Link: {live['link']['received']} received, {live['link']['lost']} lost, {live['link']['crc_errors']} "
           f"bad frames. Receive → estimate latency p50 {_fmt(live['latency_p50_ms'], '.3f')} ms, p99 "
           f"{_fmt(live['latency_p99_ms'], '.3f')} ms; observer step median "
           f"{_fmt(live['observer_step_median_us'], '.1f')} µs, p99 {_fmt(live['observer_step_p99_us'], '.1f')} µs.",
           "", "![live observer](figures/live_observer.png)", "",
           "## 5. Closing the loop: an effect the model was not told about", "",
           f"Injected on the bench: `{d['injected']}`. Diagnosis (fit on the sine_k0125 record, judged on "
           "sine_k025 and random):", ""]
    if d["accepted"]:
        for e in d["accepted"]:
            md.append(f"- accepted **{e['name']}**: {_params(e['params'], ' = ')}")
    else:
        md.append("- nothing accepted")
    md += ["", "| record | RMSE before | RMSE after |", "|---|---|---|"]
    md += [f"| {k} | {e['rmse_before']:.5f} | {e['rmse_after']:.5f} |" for k, e in d["records"].items()]
    md += ["", "Unexplained: " + ("; ".join(d["unexplained"]) or "nothing"), "",
           "The full diagnosis, with residual spectra, autocorrelations and every test's statistic: "
           "[diagnosis/report.md](diagnosis/report.md).", ""]
    md += _closed_loop_markdown(summary["closed_loop"])
    return "\n".join(md)


def _closed_loop_markdown(c: dict[str, Any]) -> list[str]:
    md = ["## 6. Closed-loop lift tracking on the bench", "",
          f"`rtlift control` (protocol version 2) tracks a ΔCL reference for {c['seconds']:g} s (steps, then a "
          f"0.125 Hz sine; `{c['reference']}`) on the bench as a hardware-in-the-loop plant, with the model "
          f"identified above. Undeclared on the bench: `{c['effect']}`. Feedforward only (inverse static map and "
          "DC gain) beside feedforward + PI feedback on the observer's estimate, run side by side on two "
          "benches. Scored on the bench's noise-free ΔCL (which the host never sees) against the reference, "
          "both low-passed at 1 Hz.", "",
          "| | RMSE vs reference (truth) | RMSE (estimate) | lost | commands sent | applied | superseded | "
          "latency p50 / p99 (ms) | saturated |", "|---|---|---|---|---|---|---|---|---|"]
    for label, key in (("feedforward only", "feedforward"), ("feedforward + feedback", "feedback")):
        r = c[key]
        md.append(f"| {label} | {r['rmse_truth']:.4f} | {_fmt(r['rmse_estimate'])} | {r['lost']} | "
                  f"{r['commands_sent']} | {r['commands_applied']} | {r['superseded']} | "
                  f"{_fmt(r['command_latency_p50_ms'], '.2f')} / {_fmt(r['command_latency_p99_ms'], '.2f')} | "
                  f"{r['saturated_fraction']:.1%} |")
    if c.get("design_warnings"):
        md += ["", "The feedback's design (python-control, `rtlift design`) misses a target; run anyway here "
               "(`--accept-design-warnings`) to show what it gives:", ""]
        md += [f"- {w}" for w in c["design_warnings"]]
    if c.get("design_cautions"):
        md += ["", "Caution on the feedback's design (its targets met on the model, which is extrapolated there):", ""]
        md += [f"- {w}" for w in c["design_cautions"]]
    md += ["", f"Feedback / feedforward RMSE: {c['ratio']:.2f}. The section took {c['elapsed_s']:.1f} s.", "",
           "![closed loop](figures/closed_loop.png)", ""]
    return md
