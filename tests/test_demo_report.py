"""The demo's closing table and report.md format every parameter type an effect can carry
(issue 44: an output nonlinearity's ``{"form": "output", "knots": 10}`` crashed stage 6/6)."""

from __future__ import annotations

import numpy as np
import pytest

from rtlift.app.demo_report import report_markdown, results_table


def _scores(corr: float, nrmse: float, rmse: float) -> dict[str, float]:
    return {"corr": corr, "nrmse": nrmse, "rmse": rmse}


def _summary(accepted: list[dict]) -> dict:
    """A demo summary as :func:`rtlift.app.demo.run_demo` writes it (numbers of a real run)."""
    link = {"received": 8000, "lost": 0, "crc_errors": 0, "duplicates": 0, "resyncs": 0, "events": 0,
            "commands_sent": 0, "commands_applied": 0}
    row = {"hybrid": _scores(0.9966, 0.0823, 0.00554), "convolution_only": _scores(0.9871, 0.424, 0.0285),
           "wiener_only": _scores(0.9687, 0.248, 0.0167), "paper_corr": 0.9596}
    loop = {"rmse_truth": 0.0186, "rmse_estimate": 0.0170, "lost": 0, "received": 7603, "commands_sent": 153,
            "commands_applied": 153, "superseded": 0, "command_latency_p50_ms": 2.31,
            "command_latency_p99_ms": 12.07, "saturated_fraction": 0.0}
    return {
        "seed": 0,
        "campaign": {"records": ["static"], "seconds": 300.7, "link": link},
        "identify": {"seconds": 57.2, "highpass": {"order": 4, "cutoff_hz": 2.0}, "wiener_order": 2},
        "validation": {name: dict(row, paper_corr=p) for name, p in
                       (("sine_k0125", 0.9596), ("sine_k025", 0.8654), ("random", 0.9277))},
        "live": {"seconds": 20.0, "scored_from_s": 3.0, "link": link,
                 "rmse_vs_truth": {"measurement": 0.00356, "open_loop_model": 0.0113, "observer": 0.00262},
                 "latency_p50_ms": 0.053, "latency_p99_ms": None, "observer_step_median_us": 22.3,
                 "observer_step_p99_us": 159.8},
        "diagnosis": {"injected": "sensor_resonance:frequency_hz=24,damping_ratio=0.06", "accepted": accepted,
                      "records": {"random_effect": {"rmse_before": 0.0286, "rmse_after": 0.00985}},
                      "unexplained": []},
        "closed_loop": {"seconds": 16.0, "elapsed_s": 42.2, "effect": "actuator_fade:final_fraction=0.75",
                        "reference": "tracking_reference.csv", "feedforward": loop,
                        "feedback": dict(loop, rmse_truth=0.0080), "ratio": 0.43},
    }


ACCEPTED = [{"name": "sensor_resonance", "params": {"frequency_hz": 24.03643628016243, "damping_ratio": 0.0592522}},
            {"name": "output_nonlinearity", "params": {"form": "output", "knots": 10,
                                                       "y": [0.0, 0.051234567, 0.1], "fit": {"rmse": 0.0012345}}}]


def test_the_closing_table_formats_numbers_strings_lists_and_mappings():
    text = results_table(_summary(ACCEPTED))
    line = next(x for x in text.splitlines() if "diagnosis found" in x)
    assert line == ("  diagnosis found: sensor_resonance (frequency_hz=24.04, damping_ratio=0.05925), "
                    "output_nonlinearity (form=output, knots=10, y=[0, 0.05123, 0.1], fit={rmse: 0.001234})")


def test_report_md_lists_every_accepted_effect_with_its_parameters():
    md = report_markdown(_summary(ACCEPTED))
    assert "- accepted **sensor_resonance**: frequency_hz = 24.04, damping_ratio = 0.05925" in md
    assert "- accepted **output_nonlinearity**: form = output, knots = 10, y = [0, 0.05123, 0.1], " \
           "fit = {rmse: 0.001234}" in md
    assert md.rstrip().endswith("![closed loop](figures/closed_loop.png)")


@pytest.mark.parametrize(("key", "line", "table_line", "absent"), [
    ("design_warnings", "|S| peak +4.31 dB > +4 dB at ΔCL 0.130 (Cμ 0.0108): at 4.00 Hz",
     "  the feedback design misses a target: |S| peak +4.31 dB > +4 dB", "misses a target"),
    ("design_cautions", "the loop crosses over at up to 0.51 Hz, above the 0.49 Hz below which",
     "  caution on the feedback design: the loop crosses over at up to 0.51 Hz", "caution"),
])
def test_a_missed_target_or_a_caution_of_the_design_is_said_in_the_table_and_the_report(key, line, table_line,
                                                                                          absent):
    s = _summary(ACCEPTED)
    s["closed_loop"][key] = [line]
    assert table_line in results_table(s) and f"- {line}" in report_markdown(s)
    s["closed_loop"][key] = []
    assert absent not in (results_table(s) + report_markdown(s)).lower()


def test_nothing_accepted_reads_as_nothing():
    assert "diagnosis found: nothing" in results_table(_summary([]))
    assert "- nothing accepted" in report_markdown(_summary([]))


def test_the_closed_loop_figure_draws_both_runs_against_the_reference(tmp_path):
    import matplotlib.image

    from rtlift.app.demo_report import tracking_figure

    t = np.arange(1600) / 400.0
    ref = np.where(t < 2.0, 0.06, 0.13)
    traces = {fb: (t, ref * k + 0.004 * np.sin(40 * t), np.where(t < 2.0, 60.0, 120.0) * k)
              for fb, k in (("off", 0.8), ("on", 1.0))}
    rows = {"off": {"rmse_truth": 0.0186}, "on": {"rmse_truth": 0.0067}}
    path = tmp_path / "closed_loop.png"
    tracking_figure(t, ref, traces, rows, str(path))
    img = matplotlib.image.imread(path)[..., :3]
    assert img.shape[1] == 1100 and np.mean(np.any(img < 0.9, axis=-1)) > 0.03     # 10 in at 110 dpi, drawn on
