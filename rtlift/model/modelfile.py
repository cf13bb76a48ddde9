"""Versioned JSON model file (format ``rtlift-model``, version 1).

Holds every parameter of a :class:`~rtlift.model.hybrid.HybridModel` (kernel, φ, HPF
coefficients and design, A B C, the nonlinearity table, augmentation stages; for the
``interaction`` structure ``convolution.interaction``: the G_H and G tables, its HF and the
delivered-momentum memory, :mod:`rtlift.blocks.interaction`), the sample
rate and units, the observer's noise settings, provenance, fit metrics and the residual
fingerprint of the identification campaign (what the diagnosis compares later records with). Loading checks
dimensions, finiteness and stability — the spectral radius of A must be < 1 — and fails
with one line naming the problem (:class:`~rtlift.core.errors.ModelFileError`).
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np

from rtlift.blocks.convolution import RingConvolution
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.interaction import InteractionConvolution
from rtlift.blocks.lti import spectral_radius
from rtlift.blocks.stages import stage_from_spec
from rtlift.blocks.wiener import NONLINEARITIES, WienerBlock
from rtlift.core.errors import ModelFileError
from rtlift.core.jsonfile import write_json_atomic
from rtlift.model.hybrid import HybridModel

FORMAT = "rtlift-model"
VERSION = 1
UNITS = {"t": "s", "cmu": "1 (momentum coefficient)", "dcl": "1 (lift coefficient increment)",
         "fs_hz": "Hz"}


def model_to_dict(model: HybridModel) -> dict[str, Any]:
    hp = model.highpass
    conv = {"kernel": model.convolution.kernel.tolist(), "phi": model.convolution.phi}
    if isinstance(model.convolution, InteractionConvolution):
        conv["interaction"] = model.convolution.params()
    return {
        "format": FORMAT,
        "version": VERSION,
        "fs_hz": model.fs_hz,
        "units": UNITS,
        "convolution": conv,
        "highpass": {"order": hp.order, "cutoff_hz": hp.cutoff_hz, "sos": hp.sos.tolist()},
        "wiener": {"A": model.wiener.A.tolist(), "B": model.wiener.B.tolist(),
                   "C": model.wiener.C.tolist(), "nonlinearity": model.wiener.nonlinearity.to_dict()},
        "input_stages": [{"name": s.name, "params": s.params()} for s in model.input_stages],
        "output_stages": [{"name": s.name, "params": s.params()} for s in model.output_stages],
        "observer": model.observer_config,
        "provenance": model.provenance,
        "metrics": model.metrics,
        "fingerprint": model.fingerprint,
    }


def _require(d: dict[str, Any], key: str, where: str) -> Any:
    if not isinstance(d, dict) or key not in d:
        raise ModelFileError(f"{where}: missing key '{key}'")
    return d[key]


def _array(value: Any, where: str, ndim: int) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ModelFileError(f"{where}: not an array of numbers") from None
    if a.ndim != ndim:
        raise ModelFileError(f"{where}: expected {ndim}-D array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ModelFileError(f"{where}: contains a non-finite number")
    return a


def model_from_dict(d: dict[str, Any], allow_unstable: bool = False, source: str = "model") -> HybridModel:
    """Build and validate a model from its dict form (see :func:`load_model`)."""
    if not isinstance(d, dict):
        raise ModelFileError(f"{source}: not a JSON object")
    if d.get("kind") == "siso":
        raise ModelFileError(f"{source}: a model of a generic t,u,y record ({d.get('structure')}), not a lift "
                             "model; observe, control and replay need a hybrid lift model (rtlift identify "
                             "--static/--single-burst/--train); a t,u,y model is for rtlift validate and diagnose")
    if d.get("format") != FORMAT:
        raise ModelFileError(f"{source}: not an rtlift model file (format {d.get('format')!r})")
    if d.get("version") != VERSION:
        raise ModelFileError(f"{source}: model file version {d.get('version')!r} is not supported "
                             f"(this rtlift reads version {VERSION})")
    fs = _require(d, "fs_hz", source)
    if not isinstance(fs, (int, float)) or not math.isfinite(fs) or fs <= 0:
        raise ModelFileError(f"{source}: fs_hz must be a positive number, got {fs!r}")
    conv = _require(d, "convolution", source)
    kernel = _array(_require(conv, "kernel", f"{source}: convolution"), f"{source}: convolution.kernel", 1)
    phi = _array(_require(conv, "phi", f"{source}: convolution"), f"{source}: convolution.phi", 0)
    if kernel.size == 0:
        raise ModelFileError(f"{source}: convolution.kernel is empty")
    hp = _require(d, "highpass", source)
    sos = _array(_require(hp, "sos", f"{source}: highpass"), f"{source}: highpass.sos", 2)
    w = _require(d, "wiener", source)
    A = _array(_require(w, "A", f"{source}: wiener"), f"{source}: wiener.A", 2)
    B = _array(_require(w, "B", f"{source}: wiener"), f"{source}: wiener.B", 1)
    C = _array(_require(w, "C", f"{source}: wiener"), f"{source}: wiener.C", 1)
    n = A.shape[0]
    if A.shape != (n, n) or B.shape != (n,) or C.shape != (n,) or n == 0:
        raise ModelFileError(f"{source}: wiener shapes do not agree: A {A.shape}, B {B.shape}, C {C.shape}")
    rho = spectral_radius(A)
    if rho >= 1.0 and not allow_unstable:
        eig = ", ".join(f"{z:.6g}" for z in np.linalg.eigvals(A))
        raise ModelFileError(f"{source}: wiener.A is not stable (spectral radius {rho:.6g} >= 1, "
                             f"eigenvalues {eig}); refusing it (allow_unstable=True to load anyway)")
    nl = _require(w, "nonlinearity", f"{source}: wiener")
    form = nl.get("form") if isinstance(nl, dict) else None
    if form not in NONLINEARITIES:
        raise ModelFileError(f"{source}: wiener.nonlinearity.form {form!r} is not one of "
                             f"{', '.join(sorted(NONLINEARITIES))}")
    try:
        model = HybridModel(
            convolution=(RingConvolution(kernel, float(phi)) if "interaction" not in conv else
                         InteractionConvolution.from_params(kernel, float(phi), conv["interaction"], float(fs))),
            highpass=HighPassFilter(sos, order=hp.get("order"), cutoff_hz=hp.get("cutoff_hz")),
            wiener=WienerBlock(A, B, C, NONLINEARITIES[form].from_dict(nl)),
            fs_hz=float(fs),
            input_stages=tuple(stage_from_spec(s["name"], s.get("params", {}), float(fs))
                               for s in d.get("input_stages", [])),
            output_stages=tuple(stage_from_spec(s["name"], s.get("params", {}), float(fs))
                                for s in d.get("output_stages", [])),
            provenance=dict(d.get("provenance") or {}),
            metrics=dict(d.get("metrics") or {}),
            observer_config=dict(d.get("observer") or {}),
            fingerprint=dict(d.get("fingerprint") or {}),
            stable=rho < 1.0,
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise ModelFileError(f"{source}: {exc}") from None
    return model


def _read_json(path: str | os.PathLike) -> Any:
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise ModelFileError(f"{path}: no such model file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{path}: cannot read model file ({exc})") from None
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from None


def load_model(path: str | os.PathLike, allow_unstable: bool = False) -> HybridModel:
    """Read and validate a model file; :class:`ModelFileError` (one line) on any problem."""
    return model_from_dict(_read_json(path), allow_unstable=allow_unstable, source=str(path))


def load_any_model(path: str | os.PathLike):
    """A lift model (:class:`HybridModel`) or a generic single-input one
    (:class:`rtlift.model.siso.SisoModel`, ``"kind": "siso"``), by what the file holds."""
    from rtlift.model.siso_file import model_from_dict as siso_from_dict

    d = _read_json(path)
    if isinstance(d, dict) and d.get("kind") == "siso":
        return siso_from_dict(d, source=str(path))
    return model_from_dict(d, source=str(path))


def save_model(model: HybridModel, path: str | os.PathLike, *, provenance: dict[str, Any] | None = None,
               metrics: dict[str, Any] | None = None, observer: dict[str, Any] | None = None) -> None:
    """Write ``model`` (updating its provenance/metrics/observer dicts when given): whole or not
    at all, :class:`~rtlift.core.errors.NumericalError` naming the first non-finite entry."""
    if provenance is not None:
        model.provenance = dict(provenance)
    if metrics is not None:
        model.metrics = dict(metrics)
    if observer is not None:
        model.observer_config = dict(observer)
    write_json_atomic(path, model_to_dict(model), stage="model file", default=_jsonable)


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"cannot write {type(o).__name__} to a model file")
