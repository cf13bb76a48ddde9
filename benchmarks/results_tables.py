"""docs/RESULTS.md's generated sections: which benchmark runs each reads, and how it renders them.

One render function per section, from the benchmarks' JSON (as ``benchmarks.results`` saved it)
to the markdown the section shows: the same columns, labels and rounding as the hand-written
tables they replace. Names and labels (a benchmark's display name, a model row's caption) live
here; every number comes from the JSON.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from benchmarks.independent_plant import params_close

# ---------------------------------------------------------------- shared formatting


def table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table (an empty cell as ``| |``)."""
    def line(cells: list[str]) -> str:
        return "|" + "|".join(f" {c} " if c else " " for c in cells) + "|"
    return "\n".join([line(header), "|" + "---|" * len(header)] + [line(row) for row in rows])


def listed(items, empty: str = "—") -> str:
    return ", ".join(items) or empty


def pct(fraction: float) -> str:
    return f"{100 * fraction:.0f} %"


def yes_no(ok: bool) -> str:
    return "yes" if ok else "**no**"


def thousands(n: int) -> str:
    return f"{n:,}".replace(",", " ")


def ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"


def us(median: float, p99: float, digits: int = 1) -> str:
    return f"{median:.{digits}f} / {p99:.{digits}f} µs"


def target(text: str, met: bool) -> str:
    """A target as the table states it, marked where this run missed it."""
    return text if met else f"{text}: **not met** in this run"


# ---------------------------------------------------------------- real measured data

REALDATA_NAMES = {"wh2009": "WH2009", "silverbox": "Silverbox (arrow, full)", "cascaded_tanks": "Cascaded Tanks"}


def _added(row: dict) -> str:
    """What the diagnosis accepted: each name, a limit's form and where it acts, a kind other than
    ``structure`` (the column's header says that kind)."""
    out = []
    for name in row["accepted"]:
        text = f"`{name}`"
        form = row.get("accepted_forms", {}).get(name)
        if form:
            text += f" (form `{form['model']}`, limit on the {form['where']})"
        kind = row.get("accepted_kinds", {}).get(name, "structure")
        out.append(text if kind == "structure" else f"{text} (kind `{kind}`)")
    return listed(out)


def render_realdata(data: dict) -> str:
    rows = [[REALDATA_NAMES.get(r["benchmark"], r["benchmark"]), f"{r['before']:.3f} {r['unit']}",
             f"**{r['after']:.3f} {r['unit']}**", _added(r), r["published"],
             f"{r['identify_seconds']:.0f} + {r['diagnose_seconds']:.0f} s"] for r in data["rows"]]
    return table(["benchmark", "Wiener (before)", "after diagnose", "added (kind `structure`)", "published",
                  "identify + diagnose"], rows)


# ---------------------------------------------------------------- the independent plant

MISSED_WORD = {"zero_drift": "drift", "sensor_resonance": "mode", "actuator_fade": "fade",
               "periodic_disturbance": "pickup", "hysteresis": "hysteresis", "delay": "delay"}
"""How the composed table names an effect that was not found ("the drift missed")."""
APPROXIMATE = {"delay+resonance", "delay+fade"}
"""Mixes the composed table marks as approximate (one effect would act on the other's imprint)."""


def _recovered(row: dict) -> str:
    values = list(row["recovered"].values())
    if all(v is None for v in values):
        return "n/a (< 10 % added)"
    return ", ".join("n/a" if v is None else pct(v) for v in values)


def _recovered_header(rows: list[dict]) -> str:
    return f"recovered ({', '.join(rows[0]['recovered'])})"


def _parameters(row: dict, detail: bool) -> str:
    """The key parameters, found vs true (the protocol's tolerances); with ``detail`` a mode's
    damping and a hysteresis's branch gains too."""
    out = []
    for name in row["accepted"]:
        got, want = row["accepted_params"][name], row["truth_params"].get(name)
        if want is None:
            continue
        text = params_close(name, got, want)[1]
        if detail and name == "sensor_resonance":
            text += f" (ζ {got['damping_ratio']:.2g} vs {want['damping_ratio']:.2g})"
        if detail and name == "hysteresis":
            g = got["rising_gain"]
            text = f"rising gain {g:.2f}, falling {g * (1 + got['magnitude']):.2f}"
        if text:
            out.append(text)
    return "; ".join(out) or "—"


def _accepted(row: dict, detail: bool) -> str:
    """The accepted effects; with ``detail`` a pickup's harmonics and what a hysteresis follows
    and is fitted to."""
    out = []
    for name in row["accepted"]:
        got = row["accepted_params"][name]
        if detail and name == "periodic_disturbance" and got.get("harmonics"):
            orders = [ordinal(h["n"]) for h in got["harmonics"]]
            name += f" (with {'the ' if len(orders) == 1 else ''}{', '.join(orders)} harmonic" \
                    f"{'s' if len(orders) > 1 else ''} as sampled)"
        elif detail and name == "hysteresis":
            driver = "the lift" if got.get("driver") == "lift" else "Cμ"
            target = "what changed" if "fitted to what changed" in row.get("fit_target", "") else "its residual"
            name += f" (driven by {driver}, fitted to {target})"
        out.append(name)
    return listed(out)


def _case_rows(data: dict, detail: bool, structure: bool) -> list[list[str]]:
    rows = []
    for r in data["rows"]:
        cells = [r["case"], listed(r["truth"]), _accepted(r, detail)]
        if structure:
            cells.append(listed(r["structure"]))
        rows.append(cells + [_parameters(r, detail), _recovered(r), yes_no(r["right"])])
    return rows


def render_independent_plant(data: dict) -> str:
    header = ["case", "truth", "accepted effects", "parameters", _recovered_header(data["rows"]), "right"]
    return table(header, _case_rows(data, detail=True, structure=False))


def render_independent_plant_field(data: dict) -> str:
    header = ["case", "truth", "accepted effects", "structure", "parameters", _recovered_header(data["rows"]),
              "right"]
    return table(header, _case_rows(data, detail=False, structure=True))


def _composed_label(case: str) -> str:
    scaled = re.fullmatch(r"(.+)x([\d.]+)", case)
    if scaled:
        return f"{scaled[1]} × {scaled[2]}"
    return case.replace("+", " + ") + (" (approximate)" if case in APPROXIMATE else "")


def _composed_accepted(row: dict) -> str:
    missed = [MISSED_WORD.get(n, n) for n in row["truth"] if n not in row["accepted"]]
    if not row["accepted"]:
        return "— (missed)" if missed else "—"
    return listed(row["accepted"]) + (f" (the {' and the '.join(missed)} missed)" if missed else "")


def render_independent_plant_composed(data: dict) -> str:
    """The mixes (those diagnosed right first) then the scaled cases, in the benchmark's order."""
    mixes = [r for r in data["rows"] if "+" in r["case"]]
    scaled = [r for r in data["rows"] if "+" not in r["case"]]
    rows = [[_composed_label(r["case"]), _composed_accepted(r), _parameters(r, detail=False), _recovered(r),
             yes_no(r["right"])] for r in sorted(mixes, key=lambda r: not r["right"]) + scaled]
    return table(["composed case", "accepted effects", "parameters", _recovered_header(data["rows"]), "right"],
                 rows)


VARIANT_LABELS = {"delay8": "delay, 8 samples", "delay14": "delay, 14 samples", "delay36": "delay, 36 samples",
                  "resonance18": "mode at 18 Hz, ζ 0.05", "mains50": "pickup at 50.03 Hz, 0.01, 3rd harmonic",
                  "drift_fast": "drift +0.02, τ 5 s", "ramp": "ramp 5e-4 per s"}
"""The variants table's words for ``benchmarks.independent_plant.VARIANTS``."""


def _variant_cell(row: dict) -> str:
    found = _composed_accepted(row) + ("" if not row["structure"] else f"; structure {listed(row['structure'])}")
    detail = _parameters(row, detail=False)
    return f"{yes_no(row['right'])}: {found}" + ("" if detail == "—" else f" ({detail})")


def render_independent_plant_variants(hybrid: dict, hybrid_field: dict, trains: dict, trains_field: dict) -> str:
    """One row per variant: right or not, and what was accepted, for the paper's hybrid and the
    full campaign's model, each in both forms."""
    runs = (hybrid, hybrid_field, trains, trains_field)
    rows = []
    for i, r in enumerate(hybrid["rows"]):
        rows.append([VARIANT_LABELS.get(r["case"], r["case"])]
                    + [_variant_cell(run["rows"][i]) for run in runs])
    totals = ["right"] + [f"{sum(x['right'] for x in run['rows'])} of {len(run['rows'])}" for run in runs]
    return table(["variant", "paper hybrid, development form", "paper hybrid, user's form",
                  "full campaign, development form", "full campaign, user's form"], rows + [totals])


# ---------------------------------------------------------------- effects on the bench

def _g4(params: dict, keys) -> str:
    return ", ".join(f"{k}={params[k]:.4g}" for k in keys)


def render_effects_table(data: dict) -> str:
    rows = []
    for name, e in data["effects"].items():
        true = e["params_true"]
        estimated = _g4(e["params_estimated"], true)
        if name == "hysteresis":
            est = e["params_estimated"]
            estimated += f" (driver {est['driver']}, τ {est['time_constant_s']:.3g} s)"
        found = "yes" if e["found"] else ("named, not accepted" if e["named"] else "no")
        recovered = "–" if e["recovered_fraction"] is None else pct(e["recovered_fraction"])
        rows.append([name, _g4(true, true), estimated, f"{e['rmse_before']:.5f}", f"{e['rmse_after']:.5f}",
                     recovered, found])
    return (table(["effect", "true parameters", "estimated", "RMSE before", "RMSE after", "recovered", "found"], rows)
            + f"\n\nThe clean records: pooled validation RMSE {data['clean_rmse']:.5f}; accepted: "
              f"{listed(data['clean_accepted'], 'nothing')}.")


# ---------------------------------------------------------------- the paper's protocol

PAPER_ROWS = {"rtlift hybrid": "**rtlift hybrid** (`rtlift identify` defaults)",
              "paper hybrid (N(Cmu) y, single-burst phi)": "paper hybrid as printed: N(Cμ)·y, single-burst φ and h",
              "paper hybrid, phi by held-out error": "paper hybrid, φ by held-out error (rtlift ≤ 0.1)",
              "convolution only": "convolution only (paper eq. 1, single-burst φ)",
              "Wiener only": "Wiener only"}


def render_paper_table(data: dict) -> str:
    records = list(data["paper_corr"])
    rows = [["paper (An, Williams & Hemati, measured in their tunnel)",
             *(f"{data['paper_corr'][n]:.4f}" for n in records), *("–" for _ in records)]]
    for key, r in data["rows"].items():
        bold = "**" if key == "rtlift hybrid" else ""
        rows.append([PAPER_ROWS.get(key, key), *(f"{bold}{r[n]['corr']:.4f}{bold}" for n in records),
                     *(f"{r[n]['nrmse']:.3f}" for n in records)])
    return table(["model", *(f"ρ {n}" for n in records), *(f"NRMSE {n}" for n in records)], rows)


# ---------------------------------------------------------------- speed and timing


def _phase(p: dict, what: str, share: bool = True) -> str:
    cpu = f", {pct(p['cpu_share'])} of a core" if share else ""
    return f"{what}: {us(p['observer_step_median_us'], p['observer_step_p99_us'])}{cpu}"


def _latency(p: dict, what: str) -> str:
    return f"{p['loop_latency_p50_ms']:.3f} / {p['loop_latency_p99_ms']:.3f} ms {what}"


def render_speed(step: dict, live: dict, load: dict, tail: dict, ident: dict, soak: dict, can: dict) -> str:
    phases = {"the sleeping loop": live, "spinning without the touch": live["spin"], "`--spin`": live["spin_touch"],
              "`--spin 0.5`": live["spin_tail"]}
    missed = [n for n, p in phases.items() if p["observer_step_median_us"] > 15 or p["observer_step_p99_us"] > 60]
    verdict = "met in every phase of this run" if not missed else f"**not met** in this run by {', '.join(missed)}"
    lost = sum(p["lost_samples"] for p in (live, load))
    rows = [
        ["one `HybridModel.step` (300-tap kernel), compiled (numba), median / p99",
         us(step["step_median_us"], step["step_p99_us"], 2), target("median ≤ 2 µs", step["step_median_us"] <= 2)],
        ["the same in pure Python (`reference_step`, same run)",
         us(step["reference_step_median_us"], step["reference_step_p99_us"], 2), ""],
        [f"batch vs streaming throughput, 10 min at 400 Hz (same output to {step['max_abs_difference']:.1e})",
         f"{step['batch_speedup']:.1f}× against the compiled step ({1e3 * step['batch_seconds']:.1f} ms vs "
         f"{step['stream_seconds']:.2f} s), {step['batch_speedup_vs_reference']:.0f}× against `reference_step`: "
         "`simulate` is one fused numba loop (the convolution scattering each non-zero burst sample, the SOS "
         "high-pass, the LTI and the map, states on the stack)", target("≥ 100×", step["batch_speedup"] >= 100)],
        *[[f"the same for the interaction structure (issue 31; {what}): step median / p99, and the batch against "
           "its pure-Python step",
           f"{us(part['step_median_us'], part['step_p99_us'], 2)} (Python step "
           f"{part['reference_step_median_us']:.1f} µs); batch {part['batch_speedup_vs_reference']:.0f}× the Python "
           f"step, batch − streamed step {part['max_abs_difference']:.1e}",
           target("median ≤ 2 µs, ≥ 100×", part["step_median_us"] <= 2 and part["batch_speedup_vs_reference"] >= 100)]
          for key, what in (("interaction", "order 3, a 2-sample delay"),
                            ("interaction_augmented", "the same with a fade, a drift, a resonance and a "
                             "lift-driven hysteresis, as the diagnosis adds them"))
          if (part := step.get(key))],
        [f"observer step in a tight loop, median / p99 ({live['state_dim']} states; compiled, same run as the "
         "live loop)",
         f"{us(live['observer_step_tight_median_us'], live['observer_step_tight_p99_us'])} (reference step "
         f"{live['observer_reference_step_tight_median_us']:.1f} µs; filterpy predict + update at "
         f"{live['state_dim']} states {live['filterpy_step_tight_median_us']:.1f} µs)", ""],
        ["observer step live on a pty at 400 Hz, median / p99, and the loop's share of a core "
         "(`observer_loop.py --spin --seconds 24`: four phases alternated in one run)",
         "; ".join([_phase(live, "sleeping in the kernel (the default)"),
                    _phase(live["spin_touch"], "`rtlift observe --spin` (spinning, the working set kept cached by "
                                               "`Observer.touch` between polls)"),
                    _phase(live["spin_tail"], "`--spin 0.5` (asleep until 0.5 ms before each sample is due)"),
                    _phase(live["spin"], "spinning without the touch")]),
         f"median ≤ 15 µs, p99 ≤ 60 µs: {verdict}"],
        ["the machine's own floor under that p99 (`machine_tail.py --seconds 30`: a fixed "
         f"{tail['work']['tight']['median_us']:.0f} µs pure-Python workload, no rtlift code, alternated in one run)",
         f"tight {us(tail['work']['tight']['median_us'], tail['work']['tight']['p99_us'])}; after sleeping to a "
         f"400 Hz deadline {us(tail['work']['sleep']['median_us'], tail['work']['sleep']['p99_us'])}; after spinning "
         f"to it {us(tail['work']['spin']['median_us'], tail['work']['spin']['p99_us'])}; a thread that never sleeps "
         f"is interrupted for > 50 µs {tail['gaps']['per_s_over_50us']:.1f} times a second (longest "
         f"{tail['gaps']['longest_us']:.0f} µs), load {tail['loadavg_1min']:.1f}",
         "the p99 a woken step cannot go below on this machine"],
        ["receive → estimate latency live, p50 / p99",
         "; ".join([_latency(live, "sleeping"), _latency(live["spin_touch"], "with `--spin`"),
                    _latency(live["spin_tail"], "with `--spin 0.5`")]),
         target("p99 ≤ 1 ms", all(p["loop_latency_p99_ms"] <= 1 for p in phases.values()))],
        ["lost samples live (the 24 s above and the 20 s under load; 60 s live serial and slcan in the tests)",
         str(lost), target("0", lost == 0)],
        ["allocations per observer step (tracemalloc, 2 000 steps)",
         f"{thousands(live['alloc_retained_bytes_after_2000_steps'])} B retained, "
         f"{thousands(live['alloc_transient_peak_bytes'])} B transient peak", ""],
        [f"identification of the standard campaign ({ident['campaign_seconds_of_data']:.0f} s of data; both "
         "forms × 9 dead times, the kernel refinement)",
         f"{ident['identify_seconds']:.2f} s (plus the observer tuning in `rtlift identify`, 8 and 12 harmonics)",
         target("< 10 s", ident["identify_seconds"] < 10)],
        [f"soak: {soak['samples'] / 1.44e6:.0f} h of frames ({soak['samples'] / 1e6:.2f} M) with "
         f"{thousands(soak['faults_injected'])} faults, decoder + observer", _soak(soak), _soak_target(soak)],
        [f"CAN soak (`soak.py --can`): {can['samples'] / 1.44e6:.0f} h as 3 frames per sample "
         f"({can['samples'] / 1e6:.2f} M samples) with {thousands(can['faults_injected'])} faults, assembler + "
         "observer", _soak(can), _soak_target(can)],
        ["live loop under load (`observer_loop.py --load`: CPU hog on the other core, this process pinned to "
         "core 0, 64 MB fsync'd disk bursts), 20 s",
         f"{load['lost_samples']} lost, receive → estimate p99 {load['loop_latency_p99_ms']:.3f} ms, step median "
         f"{load['observer_step_median_us']:.1f} µs, p99 {load['observer_step_p99_us']:.0f} µs",
         target("0 lost", load["lost_samples"] == 0)],
    ]
    return table(["what", "measured", "target"], rows)


def _soak(s: dict) -> str:
    exact = "accounted exactly" if s["accounted_exactly"] else "**not** accounted exactly"
    return f"{exact}, RSS growth {s['rss_growth_mb']:.2f} MB, {s['seconds']:.0f} s"


def _soak_target(s: dict) -> str:
    return target("exact, < 10 MB", s["accounted_exactly"] and s["rss_growth_mb"] < 10)


# ---------------------------------------------------------------- the sections


@dataclass(frozen=True)
class Section:
    """A generated part of docs/RESULTS.md: its marker name, the runs (``benchmarks.results.RUNS``)
    whose JSON it reads, and the function that renders them (one argument per run, in order)."""

    name: str
    runs: tuple[str, ...]
    render: Callable[..., str]


SECTIONS: tuple[Section, ...] = (
    Section("paper_table", ("paper_table",), render_paper_table),
    Section("independent_plant", ("independent_plant",), render_independent_plant),
    Section("independent_plant_field", ("independent_plant_field",), render_independent_plant_field),
    Section("independent_plant_composed", ("independent_plant_composed",), render_independent_plant_composed),
    Section("independent_plant_trains", ("independent_plant_trains",), render_independent_plant_field),
    Section("independent_plant_variants", ("independent_plant_variants", "independent_plant_variants_field",
                                           "independent_plant_variants_trains",
                                           "independent_plant_variants_trains_field"),
            render_independent_plant_variants),
    Section("independent_plant_trains_field", ("independent_plant_trains_field",), render_independent_plant_field),
    Section("effects_table", ("effects_table",), render_effects_table),
    Section("realdata", ("realdata",), render_realdata),
    Section("speed", ("step_latency", "observer_loop_spin", "observer_loop_load", "machine_tail", "identify_speed",
                      "soak", "soak_can"), render_speed),
)
