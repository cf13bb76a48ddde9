"""``rtlift export mat``: the model's matrices read back with scipy.io.loadmat equal the model's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.io import loadmat
from scipy.signal import dlsim

from rtlift.api import load
from rtlift.app.cli import main
from rtlift.observer import Observer

MODEL = Path(__file__).parent / "data" / "bench_model.json"


def test_the_mat_file_holds_the_models_state_space_map_kernel_and_observer_noise(tmp_path, capsys):
    out = tmp_path / "m.mat"
    assert main(["export", "mat", "--model", str(MODEL), "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    m = loadmat(out)
    model = load(MODEL)
    w = model.wiener
    n = w.A.shape[0]
    np.testing.assert_array_equal(m["A"], w.A)
    np.testing.assert_array_equal(m["B"], w.B.reshape(n, 1))
    np.testing.assert_array_equal(m["C_paper"], w.C.reshape(1, n))
    np.testing.assert_allclose(m["C"], (w.C @ w.A).reshape(1, n), rtol=1e-15)       # the standard form's
    np.testing.assert_allclose(m["D"], [[w.C @ w.B]], rtol=1e-15)
    np.testing.assert_array_equal(m["kernel"].ravel(), model.convolution.kernel)
    assert m["phi"].item() == model.convolution.phi
    np.testing.assert_array_equal(m["highpass_sos"], model.highpass.sos)
    np.testing.assert_array_equal(m["static_map_x"].ravel(), w.nonlinearity.y)
    np.testing.assert_array_equal(m["static_map_f"].ravel(), w.nonlinearity.f)
    assert str(m["static_map_form"][0]) == "output"
    obs = Observer.from_model(model)
    np.testing.assert_array_equal(m["observer_Q"], obs.kf.Q)
    assert m["observer_R"].item() == obs.config.R


def test_the_state_space_read_back_reproduces_the_models_y(tmp_path):
    """(A, B, C, D) as MATLAB's ss(A, B, C, D, Ts) reads them (scipy's dlsim: the same
    standard form) give the model's own Wiener output y (paper timing) to rounding."""
    out = tmp_path / "m.mat"
    assert main(["export", "mat", "--model", str(MODEL), "--out", str(out)]) == 0
    m = loadmat(out)
    u = np.random.default_rng(0).uniform(0.0, 0.02, 2000)
    _, y, _ = dlsim((m["A"], m["B"], m["C"], m["D"], 1.0), u)
    model = load(MODEL)
    x = np.zeros(model.wiener.A.shape[0])
    expected = []
    for v in u:
        x = model.wiener.A @ x + model.wiener.B * v
        expected.append(model.wiener.C @ x)
    np.testing.assert_allclose(y.ravel(), expected, rtol=1e-10, atol=1e-14)


def test_an_unwritable_path_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["export", "mat", "--model", str(MODEL), "--out", str(tmp_path / "no" / "m.mat")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot write" in err
