"""``rtlift export c``: the C module, compiled with ``-Werror -pedantic`` and loaded with ctypes,
equals the Python observer over a recorded run of ≥ 100 000 samples — the bench model, a paper
structure model with every effect the diagnosis adds, an interaction structure model with every
effect — in double precision to 1e-9 (relative), in single within a stated bound; its own test
program passes on its vector; a model it cannot export is refused in one line; it builds for a
Cortex-M4F without a warning.

Error measure (``_relative``): per output column (ΔĈL, open-loop ΔCL, ν, NIS), the largest
|C − Python| over the run divided by the column's largest |Python|; NaN (no measurement) must
sit on the same samples.
"""

from __future__ import annotations

import ctypes
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtlift.api import load
from rtlift.blocks.delay import Delay
from rtlift.core.rate import FS_HZ as FS
from rtlift.export.c_module import export_c
from rtlift.export.filter_spec import ExportError, bound_observer, filter_spec, steady_radius
from rtlift.export.steady import reference_observer
from rtlift.export.vectors import DOUBLE_TOLERANCE, SINGLE_TOLERANCE
from rtlift.observer import ObserverConfig
from testkit.synthetic import OUTPUT_STAGES, interaction_model, make_model, with_effects

DATA = Path(__file__).parent / "data"
CFLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
RECORDS = ("random", "sine_k0125", "sine_k025", "static", "single_burst")
"""Seed-1 bench records, concatenated: 101 480 samples (4 min 14 s at 400 Hz)."""
EVERY_STATE = ObserverConfig(R=8e-6, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4, noise_ar=(1.82, -0.85), q_noise=7e-8,
                             q_gain_h=1e-5, ripple_harmonics=4, ripple_powers=2, q_ripple=1e-8, p0_ripple=0.1,
                             max_rejections=5)
"""Every state block the observer can carry (coloured noise, gain error, ripple in two powers)."""
PLAIN = ObserverConfig(R=1.6e-5, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4, max_rejections=5)
SINGLE_ESTIMATE = 1e-3
"""Single precision's bound on the estimate ΔĈL alone (relative, as ``_relative``): measured
worst 1.2e-4 over the six (model, gain) cases on this run; every column is held to
SINGLE_TOLERANCE (1e-2; measured worst 5.6e-3, the NIS of the interaction model, full gain)."""

RUNNER = """
#include "PFX.h"
void PFX_run(long n, const double *cmu, const double *env, const double *dcl, double *out)
{
    static PFX_state st;
    PFX_out o;
    long k;
    PFX_init(&st);
    for (k = 0; k < n; k++) {
        PFX_step(&st, cmu[k], env[k], dcl[k], &o);
        out[5 * k] = o.dcl;
        out[5 * k + 1] = o.model_dcl;
        out[5 * k + 2] = o.innovation;
        out[5 * k + 3] = o.nis;
        out[5 * k + 4] = (double)o.flags;
    }
}
void PFX_run_model(long n, const double *cmu, const double *env, double *out)
{
    static PFX_state st;
    long k;
    PFX_init(&st);
    for (k = 0; k < n; k++)
        out[k] = PFX_model_step(&st, cmu[k], env[k]);
}
"""


@pytest.fixture(scope="session")
def bench_run() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(Cμ, Cμ_env, measured ΔCL, the sensor's noise: measured − true ΔCL) of the records."""
    from hil_sim.experiments import run_experiment

    recs = [run_experiment(name, 1).to_record() for name in RECORDS]
    cmu, env, dcl, true = (np.concatenate([r.extra["dcl_true"] if k == "true" else getattr(r, k) for r in recs])
                           for k in ("cmu", "cmu_envelope", "dcl", "true"))
    assert cmu.size >= 100_000
    return cmu, env, dcl, dcl - true


def _run_for(name: str, bench_run) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bench model sees the recorded ΔCL; a synthetic model its own ΔCL plus the recorded
    sensor noise (the bench's plant is not that model: its gate would reject most samples)."""
    cmu, env, dcl, noise = bench_run
    if name == "bench":
        return cmu, env, dcl
    return cmu, env, MODELS[name][0]().simulate(cmu, env).total + noise


def _paper_with_every_effect():
    """The paper's structure, N(Cμ_env) y with the lift-driven hysteresis (a play operator), a
    delay, the fade, zero drift (both kinds), the sensor resonance and a pickup."""
    rng = np.random.default_rng(4)
    model = make_model(rng, kernel_len=300, order=3)
    model.input_stages = (Delay(2 / FS, FS),)
    return with_effects(model, True, (0, 1, 2, 3), 2)


def _interaction_with_every_effect():
    """The interaction structure (delivered envelope, its static map), textbook f(y) (the
    ``output_nonlinearity`` form) with the Cμ-driven hysteresis (a switch), a delay, the fade and
    every output stage."""
    rng = np.random.default_rng(7)
    while True:
        model = interaction_model(rng, 300, 2, 1, output_form=True)
        if model.input_stages[-1].lift_arrays()[2].size:      # the static map's branch
            return with_effects(model, True, (0, 1, 2, 3), 1)


MODELS = {
    "bench": (lambda: load(DATA / "bench_model.json"), None),
    "paper_every_effect": (_paper_with_every_effect, EVERY_STATE),
    "interaction_every_effect": (_interaction_with_every_effect, EVERY_STATE),
}


@pytest.fixture(scope="session")
def reference_runs(bench_run):
    """The Python observer's outputs per (model, gain), computed once."""
    cache: dict[tuple[str, str], np.ndarray] = {}

    def get(name: str, gain: str) -> np.ndarray:
        if (name, gain) not in cache:
            factory, config = MODELS[name]
            model = factory()
            spec = filter_spec(bound_observer(model, config), gain)
            ref = reference_observer(model, config, spec)
            run = _run_for(name, bench_run)
            cache[name, gain] = np.array([ref.step(c, e, z) for c, e, z in zip(*(a.tolist() for a in run),
                                                                                 strict=True)])
        return cache[name, gain]

    return get


def _build(out: Path, prefix: str, extra: list[str] | None = None) -> ctypes.CDLL:
    runner = out / f"{prefix}_runner.c"
    runner.write_text(RUNNER.replace("PFX", prefix))
    lib = out / f"lib{prefix}.so"
    subprocess.run(["cc", *CFLAGS, "-fPIC", "-shared", str(out / f"{prefix}.c"), str(runner), "-o", str(lib),
                    "-lm", *(extra or [])], check=True, capture_output=True, text=True)
    return ctypes.CDLL(str(lib))


def _c_run(lib: ctypes.CDLL, prefix: str, cmu, env, dcl) -> np.ndarray:
    arrays = [np.ascontiguousarray(a, dtype=float) for a in (cmu, env, dcl)]
    out = np.empty((arrays[0].size, 5))
    ptr = ctypes.POINTER(ctypes.c_double)
    getattr(lib, f"{prefix}_run")(ctypes.c_long(arrays[0].size), *(a.ctypes.data_as(ptr) for a in arrays),
                                  out.ctypes.data_as(ptr))
    return out


def _relative(c: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per column of (ΔĈL, open loop, ν, NIS): max |C − Python| / max |Python| (NaNs left out:
    the caller checks they coincide)."""
    d = np.nan_to_num(np.abs(c[:, :4] - ref[:, :4]), nan=0.0)
    return d.max(axis=0) / np.nanmax(np.abs(ref[:, :4]), axis=0)


@pytest.mark.parametrize("gain", ["full", "steady"])
@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_double_module_equals_the_python_observer_over_a_recorded_run(tmp_path, bench_run, reference_runs,
                                                                          name, gain):
    factory, config = MODELS[name]
    export_c(factory(), tmp_path, "double", gain, "obs", config, vector_samples=10)
    c = _c_run(_build(tmp_path, "obs"), "obs", *_run_for(name, bench_run))
    ref = reference_runs(name, gain)
    np.testing.assert_array_equal(np.isnan(c[:, :4]), np.isnan(ref[:, :4]))
    np.testing.assert_array_equal(c[:, 4], ref[:, 4])                   # flags: the gate decided the same
    rel = _relative(c, ref)
    assert np.all(rel <= DOUBLE_TOLERANCE), rel
    assert np.sum(ref[:, 4] == 0) > 0.9 * ref.shape[0]                  # the update ran on most samples


@pytest.mark.parametrize("gain", ["full", "steady"])
@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_single_module_stays_within_its_stated_bound(tmp_path, bench_run, reference_runs, name, gain):
    factory, config = MODELS[name]
    export_c(factory(), tmp_path, "single", gain, "obs", config, vector_samples=10)
    c = _c_run(_build(tmp_path, "obs"), "obs", *_run_for(name, bench_run))
    ref = reference_runs(name, gain)
    np.testing.assert_array_equal(np.isnan(c[:, :4]), np.isnan(ref[:, :4]))
    rel = _relative(c, ref)
    assert np.all(rel <= SINGLE_TOLERANCE), rel
    assert rel[0] <= SINGLE_ESTIMATE, rel
    assert np.mean(c[:, 4] != ref[:, 4]) < 1e-3                         # a borderline gate decision at most


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), structure=st.sampled_from(["paper", "interaction"]), order=st.integers(1, 3),
       output_form=st.booleans(), delay=st.integers(0, 3), fade=st.booleans(),
       outputs=st.lists(st.integers(0, len(OUTPUT_STAGES) - 1), max_size=4), hysteresis=st.integers(0, 2),
       config=st.sampled_from(["plain", "every_state"]), gain=st.sampled_from(["full", "steady"]))
def test_any_combination_of_effects_exports_equal_to_the_python_observer(seed, structure, order, output_form, delay,
                                                                        fade, outputs, hysteresis, config, gain):
    """Random models with any mix of what the diagnosis adds, on bursts with missing samples,
    outliers and a NaN Cμ (the export's own test vector, 1000 samples): double to 1e-9."""
    rng = np.random.default_rng(seed)
    if structure == "paper":
        model = make_model(rng, kernel_len=40, order=order, output_form=output_form)
        model.input_stages = (Delay(delay / FS, FS),) if delay else ()
    else:
        model = interaction_model(rng, 40, order, delay, output_form)
    model = with_effects(model, fade, tuple(outputs), hysteresis)
    cfg = EVERY_STATE if config == "every_state" else PLAIN
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        try:
            export_c(model, out, "double", gain, "obs", cfg, vector_samples=1000)
        except ExportError as exc:          # a fixed gain that diverges for part of f: refused, not written
            assert gain == "steady" and "diverges" in str(exc) and not (out / "obs.c").exists()
            return
        rows = np.loadtxt(out / "obs_vectors.txt")
        c = _c_run(_build(out, "obs"), "obs", rows[:, 0], rows[:, 1], rows[:, 2])
    ref = rows[:, 3:]
    np.testing.assert_array_equal(np.isnan(c[:, :4]), np.isnan(ref[:, :4]))
    np.testing.assert_array_equal(c[:, 4], ref[:, 4])
    assert np.all(_relative(c, ref) <= DOUBLE_TOLERANCE), _relative(c, ref)


def test_model_step_is_the_model_alone(tmp_path, bench_run):
    model = _interaction_with_every_effect()
    export_c(model, tmp_path, "double", "steady", "obs", EVERY_STATE, vector_samples=10)
    lib = _build(tmp_path, "obs")
    cmu, env = (np.ascontiguousarray(a) for a in bench_run[:2])
    out = np.empty(cmu.size)
    ptr = ctypes.POINTER(ctypes.c_double)
    lib.obs_run_model(ctypes.c_long(cmu.size), cmu.ctypes.data_as(ptr), env.ctypes.data_as(ptr),
                      out.ctypes.data_as(ptr))
    expected = model.copy().simulate(cmu, env).total
    assert np.max(np.abs(out - expected)) <= DOUBLE_TOLERANCE * np.max(np.abs(expected))


@pytest.mark.parametrize("precision", ["double", "single"])
def test_the_generated_test_program_passes_on_its_vector(tmp_path, precision, capsys):
    """``rtlift export c`` writes the four files; the test program it writes passes on them."""
    from rtlift.app.cli import main

    assert main(["export", "c", "--model", str(DATA / "bench_model.json"), "--out", str(tmp_path),
                 "--precision", precision, "--prefix", "bench"]) == 0
    macs = re.search(r"full gain: (\d+) multiply-adds per step \(model (\d+), filter (\d+)\)", capsys.readouterr().out)
    total, model, filt = map(int, macs.groups())
    assert total == model + filt and model >= 327 and filt >= 2 * 22 * 22      # the taps; P's two d² loops
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench.c", "bench.h", "bench_test.c", "bench_vectors.txt"]
    subprocess.run(["cc", *CFLAGS, "bench.c", "bench_test.c", "-lm", "-o", "bench_test"], cwd=tmp_path, check=True,
                   capture_output=True)
    run = subprocess.run(["./bench_test", "bench_vectors.txt"], cwd=tmp_path, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout
    assert "samples 4000, NaN mismatches 0" in run.stdout and run.stdout.strip().endswith("PASS")


def test_the_test_program_fails_on_a_vector_the_module_does_not_reproduce(tmp_path):
    """The checker can fail: one expected estimate changed by 1e-6 (relative ≈ 1e-4 > 1e-9)."""
    export_c(load(DATA / "bench_model.json"), tmp_path, "double", "steady", "bench")
    lines = (tmp_path / "bench_vectors.txt").read_text().splitlines()
    cols = lines[2000].split()
    cols[3] = repr(float(cols[3]) + 1e-6)
    lines[2000] = " ".join(cols)
    (tmp_path / "bench_vectors.txt").write_text("\n".join(lines) + "\n")
    subprocess.run(["cc", *CFLAGS, "bench.c", "bench_test.c", "-lm", "-o", "bench_test"], cwd=tmp_path, check=True,
                   capture_output=True)
    run = subprocess.run(["./bench_test"], cwd=tmp_path, capture_output=True, text=True)
    assert run.returncode == 1 and run.stdout.strip().endswith("FAIL")


def test_a_model_without_a_compiled_step_is_refused_in_one_line(tmp_path, capsys):
    from rtlift.app.cli import main
    from rtlift.model.modelfile import save_model

    model = make_model(np.random.default_rng(1)).with_stages(input_stages=(Delay(1 / FS, FS), Delay(2 / FS, FS)))
    path = tmp_path / "m.json"
    save_model(model, path, observer=EVERY_STATE.to_dict())
    assert main(["export", "c", "--model", str(path), "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rtlift: error: cannot export to C:") and "delay" in err and "\n" not in err
    assert not (tmp_path / "c").exists()


def test_a_steady_gain_that_diverges_somewhere_on_the_map_is_refused(tmp_path, capsys):
    """A textbook f(y) whose slope spans 40 … 1100: the gain fixed at the operating point
    lets the error grow where the slope is steep (spectral radius > 1), so ``--gain steady`` is
    refused in one line; ``--gain full`` exports it."""
    from rtlift.app.cli import main
    from rtlift.model.modelfile import save_model

    rng = np.random.default_rng(4)
    model = make_model(rng, kernel_len=300, order=3, output_form=True)
    model.input_stages = (Delay(2 / FS, FS),)
    model = with_effects(model, True, (0, 1, 2, 3), 2)
    path = tmp_path / "m.json"
    save_model(model, path, observer=EVERY_STATE.to_dict())
    assert main(["export", "c", "--model", str(path), "--out", str(tmp_path / "s"), "--gain", "steady"]) == 2
    err = capsys.readouterr().err.strip()
    assert "diverges where the Wiener gain is" in err and "use --gain full" in err and "\n" not in err
    obs = bound_observer(model, EVERY_STATE)
    spec = filter_spec(bound_observer(model, ObserverConfig(R=1e-2, q_x=1e-12, q_bias=1e-12, p0_bias=1e-4)),
                       "steady")                      # a slow filter (large R): stable over the whole map
    assert steady_radius(obs.model, spec.F, spec.K, spec.h_fixed, spec.n_wiener, obs.layout.C)[0] < 1.0
    assert main(["export", "c", "--model", str(path), "--out", str(tmp_path / "f"), "--gain", "full"]) == 0


@pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None,
                    reason="arm-none-eabi-gcc not installed (Debian: apt-get install gcc-arm-none-eabi)")
@pytest.mark.parametrize("gain", ["steady", "full"])
@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_single_module_builds_for_a_cortex_m4f_without_a_warning(tmp_path, name, gain):
    """``-Wdouble-promotion`` too: no double arithmetic (software on that FPU) hidden in the
    float build; only the API's double arguments are converted."""
    factory, config = MODELS[name]
    export_c(factory(), tmp_path, "single", gain, "obs", config, vector_samples=10)
    run = subprocess.run(["arm-none-eabi-gcc", *CFLAGS, "-Wdouble-promotion", "-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16",
                          "-mfloat-abi=hard", "-c", "obs.c", "-o", "obs.o"], cwd=tmp_path, capture_output=True,
                         text=True)
    assert run.returncode == 0 and run.stderr == "", run.stderr
    size = subprocess.run(["arm-none-eabi-size", "obs.o"], cwd=tmp_path, capture_output=True, text=True, check=True)
    text, data, bss = (int(v) for v in size.stdout.splitlines()[1].split()[:3])
    assert 1000 < text < 64_000 and data == 0 and bss == 0     # code and constants in flash; no static state
