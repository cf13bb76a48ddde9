"""``rtlift identify`` with the burst trains (issues 18, 31) on our bench: it chooses the
interaction structure by itself, one model right for isolated bursts, close trains and
amplitude-modulated bursts; its domain; the warnings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hil_sim.experiments import EXPERIMENTS, run_experiment
from rtlift.app.cli import main
from rtlift.core.metrics import scores
from rtlift.core.records import Record, write_record
from rtlift.identify.interaction import identify_interaction
from rtlift.model.domain import DomainWatch, outside_domain
from rtlift.model.modelfile import load_model
from rtlift.model.validation import validate_record

TRAINS = ("train_T1p75", "train_T3p5", "train_T7")


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("campaign")
    paths = {}
    for name in EXPERIMENTS:
        paths[name] = d / f"{name}.csv"
        write_record(paths[name], run_experiment(name, seed=0).to_record(name))
    return d, paths


@pytest.fixture(scope="module")
def model_file(campaign):
    d, p = campaign
    out = d / "interaction.json"
    assert main(["identify", "--static", str(p["static"]), "--single-burst",
                 str(p["single_burst"]), "--trains", *(str(p[t]) for t in TRAINS), "--train",
                 str(p["sine_k0125"]), "-o", str(out)]) == 0
    return out


# Per record type, on records of another seed (seed 1): (ρ at least, NRMSE at most). Measured
# ρ / NRMSE: static 0.997/0.08, single_burst 0.872/0.49, T1p75 0.961/0.28, T3p5 0.933/0.36,
# T7 0.898/0.44, sine_k0125 0.998/0.07, sine_k025 0.995/0.11, random 0.992/0.13 (issue 31's
# Wiener input u; with m: ≥ 0.996/≤ 0.094 on the sines and random). The bench's noise-free lift:
# 0.875/0.48 on single bursts, 0.899/0.44 on T7, ≥ 0.997 on the sines and random. The paper's hybrid on the same
# records: single_burst 0.19/3.4, T3p5 0.82/1.12, T7 0.43/2.42.
BOUNDS = {"static": (0.99, 0.15), "single_burst": (0.85, 0.53), "train_T1p75": (0.94, 0.33),
          "train_T3p5": (0.91, 0.42), "train_T7": (0.87, 0.5), "sine_k0125": (0.99, 0.15),
          "sine_k025": (0.985, 0.2), "random": (0.985, 0.18)}


@pytest.mark.parametrize("name", list(BOUNDS))
def test_interaction_model_fits_every_burst_pattern_on_records_it_never_saw(model_file, name):
    rec = run_experiment(name, seed=1).to_record(name)
    s = validate_record(load_model(model_file), rec).scores
    corr, worst = BOUNDS[name]
    assert s["corr"] >= corr and s["nrmse"] <= worst, s


def test_model_file_records_the_structure_and_its_domain(model_file):
    d = json.loads(model_file.read_text())
    assert d["provenance"]["structure"]["name"] == "interaction"
    choice = d["provenance"]["structure"]["choice"]
    assert choice["chosen"] == "interaction" and "include burst trains" in choice["why"]
    assert "interaction" in d["convolution"]
    dom = d["provenance"]["domain"]
    # bursts every 51, 57, 114 and 229 samples (8 Hz and the three trains), and isolated ones
    assert [round(p * 400) for p in dom["burst_periods_s"]] == [50, 57, 114, 229]
    assert dom["isolated_bursts"] is True
    assert dom["cmu_max"] == pytest.approx(0.022, rel=0.01)


# The known answer's bounds, from the measured spread (issue 44; 17 identifications, /tmp scripts,
# on this machine under load). The records the identification is fitted on reproduce tightly:
# NRMSE ≤ 0.0296 in every run. sine_k025 and random are never in it, and there the result is not
# determined to rounding: the chosen Wiener order 4 (the truth's is 2) leaves a flat direction in
# the output-error fit, and ΔCL perturbed by white noise of 1e-15, 1e-14 or 1e-12 relative lands it
# in one of two minima of equal held-out error (order 4: 0.03301–0.03304 in every run; τ, HF,
# Wiener input, order and dead time chosen alike) that extrapolate differently: sine_k025
# 0.0668–0.0685 / random 0.0715–0.0725 (unperturbed, with OpenBLAS at 1 or 2 threads — the
# identification holds BLAS to one thread anyway —; 6 of 7 runs at 1e-12, 1 of 4 at 1e-14, 1 of 3
# at 1e-15), or sine_k025 0.0942–0.0967 / random 0.0794–0.0800 (the others; the other machine's
# failure, numpy 2.4.6, scipy 1.17.1, numba 0.68.1: sine_k025 0.0959). Bounds: 0.05 on the fitted
# records (1.7 × their largest), 0.12 on the two held-out types (1.24 × the largest seen); the
# paper's hybrid on the bench's noisy sine_k025 is at 0.34. A fix of the cause belongs to the
# identification (rtlift/identify/interaction.py: an order within a few % of a smaller one), not here.
KNOWN_ANSWER_NRMSE = {"sine_k025": 0.12, "random": 0.12}
KNOWN_ANSWER_NRMSE_FITTED = 0.05


def test_identification_recovers_the_structure_from_its_own_noise_free_data(model_file):
    """Known answer, approximate: records of the bench's programs whose ΔCL is a model of the
    structure itself (the one identified on the bench, noise free). The identification re-estimates
    N from the truth's static record and h from its single bursts (N within 9 % of the truth's),
    so the truth is not exactly in its model set: it picks the truth's τ and HF cutoff and
    reproduces every record type, not the HF order or the Wiener order (the truth: HF order 4,
    Wiener order 2; got 2 and 4 — held-out NRMSE 0.033 against 0.034 with Wiener order 3; the
    truth's own structure fitted gives 0.032 held out, NRMSE ≤ 0.060). The bounds are set from the
    spread measured under rounding perturbations (``KNOWN_ANSWER_NRMSE`` above): the records it
    is fitted on within 0.05, sine_k025 and random, which it never sees and where the order-4 fit
    has two minima of equal held-out error (0.067 or 0.095 on sine_k025), within 0.12."""
    truth = load_model(model_file)
    recs = {}
    for name in EXPERIMENTS:
        commanded = run_experiment(name, seed=0).to_record()      # the program's Cμ, as the bench fires it
        cmu, env = commanded.cmu, commanded.cmu_envelope
        truth.reset()
        recs[name] = Record(np.arange(env.size) / 400.0, cmu, env, truth.simulate(cmu, env).total, name=name)
    idf = identify_interaction(recs["static"], recs["single_burst"], [recs[t] for t in TRAINS], recs["sine_k0125"])
    got, want = idf.provenance, truth.provenance
    assert got["structure"]["time_constant_s"] == want["structure"]["time_constant_s"]
    assert got["structure"]["highpass"]["cutoff_hz"] == want["structure"]["highpass"]["cutoff_hz"]
    for name, rec in recs.items():
        idf.model.reset()
        nrmse = scores(rec.dcl, idf.model.simulate(rec.cmu, rec.cmu_envelope).total)["nrmse"]
        assert nrmse < KNOWN_ANSWER_NRMSE.get(name, KNOWN_ANSWER_NRMSE_FITTED), (name, nrmse)


def test_validate_warns_in_one_line_when_a_record_leaves_the_domain(model_file, tmp_path, capsys):
    rec = run_experiment("sine_k0125", seed=1).to_record("every_0p2_s")
    rec.cmu = np.where(np.arange(len(rec)) % 80 < 4, rec.cmu_envelope, 0.0)     # bursts every 0.2 s: unseen
    path = tmp_path / "every_0p2_s.csv"
    write_record(path, rec)
    assert main(["validate", "--model", str(model_file), str(path)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "warning: every_0p2_s: outside the model's domain: burst periods 0.2 s" in err[0]


def test_validate_says_nothing_for_records_inside_the_domain(model_file, campaign, capsys):
    _, p = campaign
    assert main(["validate", "--model", str(model_file), *(str(p[n]) for n in EXPERIMENTS)]) == 0
    assert capsys.readouterr().err == ""


def test_live_watch_reports_once_where_the_record_check_does(model_file):
    dom = load_model(model_file).provenance["domain"]
    cmu = np.where(np.arange(4000) % 51 < 4, 0.01, 0.0)
    cmu[2040:] = np.where(np.arange(1960) % 80 < 4, 0.01, 0.0)              # from 5.1 s on every 0.2 s
    watch = DomainWatch(dom, 400.0)
    lines = [(k, line) for k, c in enumerate(cmu) if (line := watch.step(c, 0.01))]
    assert outside_domain(dom, cmu, np.full(4000, 0.01), 400.0) is not None
    assert len(lines) == 1 and lines[0][0] == 2120 and "burst period 0.2 s" in lines[0][1]


@pytest.mark.parametrize("argv, message", [
    (["--structure", "wiener"], "--structure wiener is for a generic --record"),
    (["--structure", "interaction", "--phi", "train"], "--phi: not a choice of --structure interaction"),
])
def test_identify_refuses_a_structure_or_option_that_does_not_fit_in_one_line(campaign, tmp_path, capsys,
                                                                             argv, message):
    _, p = campaign
    code = main(["identify", "--static", str(p["static"]), "--single-burst", str(p["single_burst"]), "--train",
                 str(p["sine_k0125"]), *argv, "-o", str(tmp_path / "m.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0]
