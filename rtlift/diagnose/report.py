"""Write a diagnosis: ``report.json`` (INTERFACES.md schema), ``residual_tests.json`` (every
test's verdict and statistic, before and after), ``report.md`` with figures, and
``model_augmented.json`` (loadable by ``rtlift validate``)."""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from rtlift.core.registry import SCHEMAS
from rtlift.diagnose.selection import Diagnosis
from rtlift.model.modelfile import save_model
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
        ax.set_ylabel("residual ΔCL")
        ax.set_title(name, fontsize=9)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, paths["residual_time"]), dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(9, 3.5))
    for name in names:
        for label, res in (("before", diag.residual_before), ("after", diag.residual_after)):
            f, p = welch_psd(res[name][s:], fs)
            ax.semilogy(f, p, lw=0.7, label=f"{name} {label}")
    ax.set_xlabel("f (Hz)")
    ax.set_ylabel("PSD (1/Hz)")
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


def markdown(diag: Diagnosis, figures: dict[str, str]) -> str:
    r = diag.report
    lines = ["# Diagnosis report", "",
             f"Scores: {r['scoring']}. Residual tests from sample {diag.start} on.", "",
             f"Fingerprint: {r['fingerprint']}.", "",
             f"Fits: {r['fit_target']}.", "",
             "## What each record is compared with", "",
             "Found from each record's input (burst period, on-time, envelope, levels), never its name.", "",
             "| record | reference | identification record | nearest input | distance | why |",
             "|---|---|---|---|---|---|"]
    for name, ref in r.get("references", {}).items():
        dist = "–" if ref["distance"] is None else f"{ref['distance']:.2f}"
        lines.append(f"| {name} | {ref['source']} | {ref['entry'] or '–'} | {ref['nearest'] or '–'} | {dist} | "
                     f"{ref['text']} |")
    lines += ["",
              "## Error before and after", "",
              "| record | ρ before | ρ after | NRMSE before | NRMSE after | RMSE before | RMSE after |",
              "|---|---|---|---|---|---|---|"]
    for name, b in r["baseline"]["records"].items():
        a = r["augmented"]["records"][name]
        lines.append(f"| {name} | {b['corr']:.4f} | {a['corr']:.4f} | {b['nrmse']:.4f} | {a['nrmse']:.4f} "
                     f"| {b['rmse']:.5f} | {a['rmse']:.5f} |")
    lines += ["", "## Effects tried", "",
              "| effect | kind | accepted | parameters | validation RMSE before → after |",
              "|---|---|---|---|---|"]
    for e in r["effects"]:
        params = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in e["params"].items())
        lines.append(f"| {e['name']} | {e['kind']} | {'**yes**' if e['accepted'] else 'no'} | {params or '–'} | "
                     f"{e['validation_rmse_before']:.5f} → {e['validation_rmse_after']:.5f} |")
    sel = r["selection"]
    lines += ["", "## Competing explanations", "", f"Rule: {sel['rule']}. Pool: {', '.join(sel['pool']) or '–'}; "
              f"chosen: {', '.join(sel['chosen']) or 'nothing'}.", "",
              "| combination | parameters | validation RMSE | admissible | why |", "|---|---|---|---|---|"]
    for c in sorted(sel["combinations"], key=lambda c: c["validation_rmse"]):
        lines.append(f"| {' + '.join(c['members'])} | {c['parameters']} | {c['validation_rmse']:.5f} | "
                     f"{'yes' if c['admissible'] else 'no'} | {c['why']} |")
    lines += ["", "Evidence:", ""] + [f"- **{e['name']}** ({SCHEMAS[e['name']].meaning}): {e['evidence']}"
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
    prov = dict(diag.augmented.provenance)
    prov["diagnose"] = {"accepted": [{"name": e["name"], "kind": e["kind"]} for e in diag.report["effects"]
                                     if e["accepted"]],
                        **(provenance or {})}
    metrics = dict(diag.augmented.metrics)
    metrics["diagnose"] = diag.report["augmented"]["records"]
    save_model(diag.augmented, os.path.join(out_dir, "model_augmented.json"), provenance=prov, metrics=metrics)
