"""Write a diagnosis of either kind — a lift model's (:func:`rtlift.diagnose.lift.diagnose`)
or a generic ``t,u,y`` model's (:func:`rtlift.sysid.diagnose.diagnose_generic`), both a
:class:`~rtlift.diagnose.diagnosis.Diagnosis`: ``report.json`` (INTERFACES.md schema, the same
keys for both kinds), ``residual_tests.json`` (every test's verdict and statistic, before and
after), ``report.md`` with figures, and ``model_augmented.json`` (loadable by ``rtlift validate``).
A section with nothing to say for a kind (a generic model has no fingerprint references) is left
out of ``report.md``."""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from rtlift.diagnose.diagnosis import Diagnosis
from rtlift.effects import BY_NAME
from rtlift.model.modelfile import save_model
from rtlift.model.siso_file import save_siso_model
from rtlift.residual.stats import welch_psd


def _fig_paths(out: str) -> dict[str, str]:
    return {k: os.path.join("figures", f"{k}.png") for k in ("residual_time", "residual_spectrum",
                                                              "residual_autocorr")}


def plot(diag: Diagnosis, out_dir: str, fs: float) -> dict[str, str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = _fig_paths(out_dir)
    os.makedirs(os.path.join(out_dir, "figures"), exist_ok=True)
    names = list(diag.residual_before)
    s = diag.start

    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.2 * len(names)), squeeze=False, sharex=True)
    for ax, name in zip(axes[:, 0], names, strict=True):
        e0, e1 = diag.residual_before[name], diag.residual_after[name]
        t = np.arange(e0.size) / fs
        ax.plot(t[s:], e0[s:], lw=0.5, label="before")
        ax.plot(t[s:], e1[s:], lw=0.5, label="after", alpha=0.8)
        ax.set_ylabel("residual ΔCL" if diag.kind == "lift" else "residual y")
        ax.set_title(name, fontsize=9)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, paths["residual_time"]), dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(9, 3.5))
    for name in names:
        for label, res in (("before", diag.residual_before), ("after", diag.residual_after)):
            e = res[name][s:]     # a generic record's segments: in samples (its time scale is its own)
            f, p = welch_psd(e, fs) if diag.kind == "lift" else welch_psd(e, fs, e.size / fs)
            ax.semilogy(f, p, lw=0.7, label=f"{name} {label}")
    ax.set_xlabel("f (Hz)")
    ax.set_ylabel("PSD (1/Hz)" if diag.kind == "lift" else "PSD (y²/Hz)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, paths["residual_spectrum"]), dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(9, 3.2))
    first = names[0]
    for label, tests in (("before", diag.tests_before), ("after", diag.tests_after)):
        w = tests[first]["whiteness"].data
        ax.plot(w["lags"], w["r"], marker=".", lw=0.8, label=f"{first} {label}")
    bound = diag.tests_before[first]["whiteness"].data["bound"]
    ax.axhline(bound, color="k", ls="--", lw=0.7)
    ax.axhline(-bound, color="k", ls="--", lw=0.7, label="99 % bound")
    ax.set_xlabel("lag (samples)")
    ax.set_ylabel("r_ee")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, paths["residual_autocorr"]), dpi=90)
    plt.close(fig)
    return paths


def tests_json(diag: Diagnosis) -> dict[str, Any]:
    def one(tests: dict) -> dict:
        return {rec: {k: t.to_dict() for k, t in d.items()} for rec, d in tests.items()}
    return {"version": 2, "tests_from_sample": diag.start, "before": one(diag.tests_before),
            "after": one(diag.tests_after), "combinations": diag.rounds}


def param_text(v: Any) -> str:
    """A parameter as the report's table shows it: numbers to 4 digits, lists and mappings of
    them too; a list of records (a pickup's harmonics) as Python writes it."""
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)) and not any(isinstance(x, dict) for x in v):
        return "[" + ", ".join(param_text(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {param_text(x)}" for k, x in v.items()) + "}"
    return f"{v}"


def markdown(diag: Diagnosis, figures: dict[str, str]) -> str:
    r = diag.report
    lift = diag.kind == "lift"
    num = ".5f" if lift else ".5g"       # a generic record's output has any scale
    lines = ["# Diagnosis report", "",
             f"Scores: {r['scoring']}. Residual tests from sample {diag.start} on.", "",
             f"Fingerprint: {r['fingerprint']}.", "",
             f"Fits: {r['fit_target']}.", ""]
    if r["references"] is not None:
        lines += ["## What each record is compared with", "",
                  "Found from each record's input (burst period, on-time, envelope, levels), never its name.", "",
                  "| record | reference | identification record | nearest input | distance | why |",
                  "|---|---|---|---|---|---|"]
        for name, ref in r["references"].items():
            dist = "–" if ref["distance"] is None else f"{ref['distance']:.2f}"
            lines.append(f"| {name} | {ref['source']} | {ref['entry'] or '–'} | {ref['nearest'] or '–'} | {dist} "
                         f"| {ref['text']} |")
        lines.append("")
    lines += ["## Error before and after", "",
              "| record | ρ before | ρ after | NRMSE before | NRMSE after | RMSE before | RMSE after |",
              "|---|---|---|---|---|---|---|"]
    for name, b in r["baseline"]["records"].items():
        a = r["augmented"]["records"][name]
        lines.append(f"| {name} | {b['corr']:.4f} | {a['corr']:.4f} | {b['nrmse']:.4f} | {a['nrmse']:.4f} "
                     f"| {b['rmse']:{num}} | {a['rmse']:{num}} |")
    lines += ["", "## Effects tried", "",
              "| effect | kind | accepted | parameters | validation RMSE before → after |",
              "|---|---|---|---|---|"]
    for e in r["effects"]:
        params = ", ".join(f"{k}={param_text(v)}" for k, v in e["params"].items())
        lines.append(f"| {e['name']} | {e['kind']} | {'**yes**' if e['accepted'] else 'no'} | {params or '–'} | "
                     f"{e['validation_rmse_before']:{num}} → {e['validation_rmse_after']:{num}} |")
    sel = r["selection"]
    lines += ["", "## Competing explanations", "", f"Rule: {sel['rule']}. Pool: {', '.join(sel['pool']) or '–'}; "
              f"chosen: {', '.join(sel['chosen']) or 'nothing'}.", "",
              "| combination | parameters | validation RMSE | level-free | admissible | why |",
              "|---|---|---|---|---|---|"]
    for c in sorted(sel["combinations"], key=lambda c: c["level_free_rmse"]):
        count = c["parameters"] if c["parameters"] is not None or lift else "–"   # a structure's: not counted
        lines.append(f"| {' + '.join(c['members'])} | {count} | {c['validation_rmse']:{num}} | "
                     f"{c['level_free_rmse']:{num}} | "
                     f"{'yes' if c['admissible'] else 'no'} | {c['why']} |")
    lines += ["", "Evidence:", ""] + [f"- **{e['name']}** ({BY_NAME[e['name']].meaning}): {e['evidence']}"
                                      for e in r["effects"]]
    lines += ["", "## Unexplained", ""] + ([f"- {u}" for u in r["unexplained"]] or ["- nothing"])
    first = next(iter(diag.tests_before))
    lines += ["", f"## Residual tests on `{first}` (before → after)", "", "| test | before | after |",
              "|---|---|---|"]
    for k, t in diag.tests_before[first].items():
        a = diag.tests_after[first][k]
        lines.append(f"| {k} | {t.verdict}: {t.detail} | {a.verdict}: {a.detail} |")
    lines += ["", "## Figures", "", f"![residual in time]({figures['residual_time']})", "",
              f"![residual spectrum]({figures['residual_spectrum']})", "",
              f"![residual autocorrelation]({figures['residual_autocorr']})", ""]
    return "\n".join(lines)


def write(diag: Diagnosis, out_dir: str, provenance: dict[str, Any] | None = None) -> None:
    """The report files and ``model_augmented.json`` of ``diag`` in ``out_dir``; ``provenance``
    (where the records came from) goes into a lift model file's ``provenance.diagnose``."""
    os.makedirs(out_dir, exist_ok=True)
    fs = diag.augmented.fs_hz
    figures = plot(diag, out_dir, fs)
    with open(os.path.join(out_dir, "report.json"), "w", encoding="utf-8") as f:
        json.dump(diag.report, f, indent=1, allow_nan=True)
        f.write("\n")
    with open(os.path.join(out_dir, "residual_tests.json"), "w", encoding="utf-8") as f:
        json.dump(tests_json(diag), f, indent=1, allow_nan=True, default=float)
        f.write("\n")
    with open(os.path.join(out_dir, "report.md"), "w", encoding="utf-8") as f:
        f.write(markdown(diag, figures))
    if diag.kind != "lift":
        save_siso_model(diag.augmented, os.path.join(out_dir, "model_augmented.json"))
        return
    prov = dict(diag.augmented.provenance)
    prov["diagnose"] = {"accepted": [{"name": e["name"], "kind": e["kind"]} for e in diag.report["effects"]
                                     if e["accepted"]],
                        **(provenance or {})}
    metrics = dict(diag.augmented.metrics)
    metrics["diagnose"] = diag.report["augmented"]["records"]
    save_model(diag.augmented, os.path.join(out_dir, "model_augmented.json"), provenance=prov, metrics=metrics)
