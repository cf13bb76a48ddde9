"""The ``nonlinear_feedback`` structure with a Bouc–Wen state in its map (issue 48: Noël & Schoukens'
hysteretic benchmark, m ÿ + c ẏ + k y + z = u, ż = α ẏ − β(γ|ẏ|z + δ ẏ|z|)):

    dz/dy = α − g sgn(ẏ) z − d |z|,   v = u − k₂y² − k₃y³ − z,

coupled to the linear block by the trapezoidal rule at M substeps a sample
(:class:`rtlift.model.siso.FeedbackModel`).

Stepped and simulated in chunks alike to 1e-12; the file round-trips; without hysteresis the
model and its file are as before, bit for bit; identified from a record of a hysteretic plant, the
hysteretic variant is chosen by its held-out error and reaches the noise, where the plain one
(the structure before) does not.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from rtlift.core.records import SisoRecord
from rtlift.model.siso import FeedbackModel
from rtlift.model.siso_file import model_from_dict
from rtlift.sysid import feedback
from rtlift.sysid.common import SisoOptions
from rtlift.sysid.identify import identify_siso

FS = 750.0


def _plant(alpha: float = 5e4, g: float = 800.0, d: float = -1100.0, substeps: int = 4, **kw) -> FeedbackModel:
    """A mass on a spring with a Bouc–Wen force, m = 2 kg, c = 10 N s/m, k = 5·10⁴ N/m (the
    benchmark's values), its linear part discretised at ``substeps`` FS with the input held."""
    b, a = signal.cont2discrete(([1.0], [2.0, 10.0, 5e4]), 1.0 / FS / substeps, "zoh")[:2]
    return FeedbackModel(a[1:], np.ravel(b)[1:], [0.0, 0.0], FS, hysteresis=(alpha, g, d), substeps=substeps, **kw)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.lists(st.integers(1, 300), min_size=1, max_size=4))
def test_a_hysteretic_feedback_model_steps_and_chunks_alike_and_round_trips(seed, cuts):
    rng = np.random.default_rng(seed)
    # g ≥ |d| (γ ≥ |δ|, Bouc–Wen's bounded-z condition) and g|Δy| ≲ 0.1 at these inputs: z stays bounded
    g = rng.uniform(200.0, 1000.0)
    m1 = _plant(rng.uniform(1e4, 8e4), g, rng.uniform(-g, g), int(rng.integers(1, 5)),
                offset=rng.uniform(-1e-4, 1e-4))
    m2 = model_from_dict(json.loads(json.dumps(m1.to_dict())))
    assert m2.hysteresis == m1.hysteresis and m2.substeps == m1.substeps and m2.state_size == 2 * m1.n + 2
    u = rng.normal(size=sum(cuts)) * 20.0
    stepped = np.array([m1.step(v) for v in u])
    assert np.all(np.isfinite(stepped))
    parts, i = [], 0
    for c in cuts:
        m2.set_state(m2.get_state())
        parts.append(m2.simulate(u[i:i + c]))
        i += c
    scale = float(np.max(np.abs(stepped)))
    np.testing.assert_allclose(np.concatenate(parts), stepped, atol=1e-12 * scale, rtol=0)
    np.testing.assert_allclose(m1.get_state(), m2.get_state(), atol=1e-12 * max(scale, 1.0), rtol=1e-12)


def test_without_hysteresis_the_model_and_its_file_are_as_before():
    """No hysteresis: no key in the file, the state as before; with one, [z, u_prev] end the state,
    z moves the output, and what the recursion cannot take is refused."""
    b, a = signal.cont2discrete(([1.0], [2.0, 10.0, 5e4]), 1.0 / FS, "zoh")[:2]
    plain = FeedbackModel(a[1:], np.ravel(b)[1:], [0.0, 0.0], FS)
    assert "bouc_wen" not in plain.to_dict() and "substeps" not in plain.to_dict() and plain.state_size == 4
    u = np.random.default_rng(3).normal(size=2000) * 50.0
    y = plain.simulate(u)
    linear = signal.lfilter(np.ravel(b), a, u)                # k₂ = k₃ = 0: the linear block alone
    np.testing.assert_allclose(y, linear, atol=1e-12 * np.max(np.abs(linear)), rtol=0)
    hyst = _plant(substeps=1)
    assert hyst.state_size == 6 and not np.any(hyst.get_state())
    yh = hyst.simulate(u)
    assert hyst.get_state()[-2] != 0.0 and hyst.get_state()[-1] == u[-1]
    assert np.sqrt(np.mean((yh - y) ** 2)) > 0.3 * np.std(y)
    for bad in ({"integrating": True}, {"feedthrough": 1e-9}, {"state_limits": (-1.0, 1.0)}):
        with pytest.raises(ValueError, match="hysteretic"):
            FeedbackModel([-0.5], [0.1], [0.0, 0.0], FS, hysteresis=(1.0, 0.0, 0.0), **bad)


def test_a_hysteretic_plant_is_identified_with_its_hysteresis(monkeypatch):
    """A record of the hysteretic plant (a multisine of 50 N RMS, 5-150 Hz, 6000 samples, output
    noise 8 µm): the hysteretic variant holds out within 1.5x the noise; the plain structure alone
    (the variant switched off, as before it existed) holds out at more than 5x the noise."""
    rng = np.random.default_rng(7)
    n = 6000
    f = np.fft.rfftfreq(n, 1.0 / FS)
    spec = np.where((f >= 5) & (f <= 150), np.exp(2j * np.pi * rng.uniform(size=f.size)), 0)
    u = np.fft.irfft(spec, n)
    u *= 50.0 / np.std(u)
    noise = 8e-6
    y = _plant().simulate(u) + noise * rng.standard_normal(n)
    rec = SisoRecord(np.arange(n) / FS, u, y, name="bw")
    opt = SisoOptions(feedback_orders=(2, 3))
    model = identify_siso(rec, "nonlinear_feedback", options=opt)
    assert model.hysteretic and model.substeps == 4 and "bouc_wen" in model.provenance
    assert model.metrics["holdout_rmse"] < 1.5 * noise
    monkeypatch.setattr(feedback, "HYSTERESIS_ORDERS", 0)
    plain = identify_siso(rec, "nonlinear_feedback", options=opt)
    assert not plain.hysteretic and plain.metrics["holdout_rmse"] > 5 * noise
