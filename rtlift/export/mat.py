"""``rtlift export mat``: the model (and its observer's Q and R) as a MATLAB ``.mat`` file
(:func:`scipy.io.savemat`, MATLAB 5 format), for a lab that checks or reuses it in MATLAB.

Variables (names as in the paper and :mod:`rtlift.observer`):

- ``A``, ``B`` (n×1), ``C`` (1×n), ``D`` (1×1): the Wiener LTI in MATLAB's (and scipy's)
  standard form, s(k+1) = A s(k) + B u(k), y(k) = C s(k) + D u(k), so that ``ss(A, B, C, D, Ts)``
  gives the model's y. The model's own timing (the paper's) is x(k) = A x(k−1) + B u(k),
  y(k) = C_paper x(k): the same system with s(k) = x(k−1), C = C_paper A, D = C_paper B;
  ``C_paper`` is written too;
- ``static_map_form`` (``input_gain``: ΔCL_L = N(Cμ_env)·y, or ``output``: ΔCL_L = f(y)),
  ``static_map_x`` (the Cμ_env grid, or the y grid) and ``static_map_f`` (N, or f) — linear
  between the points;
- ``kernel`` h(j) (L samples) and ``phi`` φ: ΔCL_H = HF(φ Σ_j h(j) Cμ(k − j));
- ``highpass_sos`` (sections × 6, scipy's ``[b0 b1 b2 a0 a1 a2]``) of HF;
- ``fs_hz``, ``structure`` (``hybrid`` or ``interaction``: the burst part's own gains are not
  written for the latter), ``input_stages`` and ``output_stages`` (the effects' names);
- with observer settings in the model file: ``observer_Q`` (dim_x × dim_x), ``observer_R``,
  and the state-space matrices they belong to, ``observer_F``, ``observer_G`` and the fixed
  part of the measurement row ``observer_h`` (:class:`~rtlift.observer.layout.StateLayout`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy.io import savemat

from rtlift.blocks.interaction import InteractionConvolution
from rtlift.export.filter_spec import ExportError
from rtlift.model.hybrid import HybridModel
from rtlift.observer import Observer


def model_matrices(model: HybridModel) -> dict[str, Any]:
    """The variables of the ``.mat`` file (module docstring)."""
    w = model.wiener
    n = w.A.shape[0]
    nl = w.nonlinearity
    if hasattr(nl, "gain_at"):
        form, x, f = "input_gain", nl.cmu, nl.gain
    else:
        form, x, f = "output", nl.y, nl.f
    interaction = isinstance(model.convolution, InteractionConvolution)
    highpass = model.convolution.highpass if interaction else model.highpass
    out: dict[str, Any] = {
        "A": np.asarray(w.A, float), "B": np.asarray(w.B, float).reshape(n, 1),
        "C": (w.C @ w.A).reshape(1, n), "D": np.array([[float(w.C @ w.B)]]),
        "C_paper": np.asarray(w.C, float).reshape(1, n),
        "static_map_form": form, "static_map_x": np.asarray(x, float), "static_map_f": np.asarray(f, float),
        "kernel": np.asarray(model.convolution.kernel, float), "phi": float(model.convolution.phi),
        "highpass_sos": np.asarray(highpass.sos, float), "fs_hz": float(model.fs_hz),
        "structure": "interaction" if interaction else "hybrid",
        "input_stages": np.array([st.name for st in model.input_stages], dtype=object),
        "output_stages": np.array([st.name for st in model.output_stages], dtype=object),
    }
    if model.observer_config:
        obs = Observer.from_model(model)
        out.update(observer_Q=obs.kf.Q.copy(), observer_R=float(obs.config.R), observer_F=obs.layout.F.copy(),
                   observer_G=obs.layout.G.reshape(-1, 1).copy(), observer_h=obs.layout.h_fixed.reshape(1, -1).copy())
    return out


def export_mat(model: HybridModel, path: str | Path) -> dict[str, Any]:
    """Write :func:`model_matrices` to ``path``; returns them."""
    data = model_matrices(model)
    try:
        savemat(str(path), data, do_compression=True, oned_as="column")
    except OSError as exc:
        raise ExportError(f"{path}: cannot write ({exc.strerror})") from None
    return data
