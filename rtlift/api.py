"""The Python API of ``rtlift identify``, ``validate`` and ``diagnose``: the functions those
commands call, for scripts and notebooks (docs/API.md has a runnable example).

Records and models may be given as paths or as loaded objects (:class:`~rtlift.core.records.Record`
for lift records, :class:`~rtlift.core.records.SisoRecord` for generic ``t,u,y`` records; a
:class:`~rtlift.model.hybrid.HybridModel` or a generic model from :func:`identify_record`). Bad
input raises :class:`~rtlift.core.errors.UserError` with the one line the command prints.

- :func:`identify` — the hybrid lift model from a campaign (static sweep, single bursts,
  training record; ``structure="interaction"`` also the burst trains), observer settings tuned;
- :func:`identify_record` — a single-input model of one generic ``t,u,y`` record;
- :func:`validate` — ρ, NRMSE and RMSE of a model on records, free run from rest (figures optional);
- :func:`diagnose` — what the model misses: the report and the augmented model (written to
  ``out`` as ``report.json``, ``report.md`` and ``model_augmented.json`` when given);
- :func:`diagnose_run` — the same on one long record, fitted on its first part, judged on the rest.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rtlift.core.errors import UserError, require_finite
from rtlift.core.registry import MODEL_STRUCTURE_NAMES

PathLike = str | os.PathLike
LIFT_STRUCTURES = ("paper", "interaction")
GENERIC_STRUCTURES = MODEL_STRUCTURE_NAMES


def _lift(record: Any, min_samples: int = 2):
    from rtlift.core.records import read_record

    return read_record(record, min_samples=min_samples) if isinstance(record, (str, os.PathLike)) else record


def _generic(record: Any, min_samples: int = 2):
    from rtlift.core.records import read_siso_record

    return read_siso_record(record, min_samples=min_samples) if isinstance(record, (str, os.PathLike)) else record


def load(model: Any):
    """A model object from a path (lift or generic, by what the file holds) or as given."""
    from rtlift.model.modelfile import load_any_model

    return load_any_model(model) if isinstance(model, (str, os.PathLike)) else model


def is_generic(model: Any) -> bool:
    """Is ``model`` a single-input model of generic ``t,u,y`` records (not a lift model)?"""
    from rtlift.model.siso import SISO_MODELS

    return isinstance(model, SISO_MODELS)


def identify(static: Any, single_burst: Any, train: Any, *, trains: Sequence[Any] = (), structure: str | None = None,
             order: int | None = None, form: str = "auto", phi: str = "auto", dead_time: int | None = None,
             kernel: str = "auto", envelope: str = "recorded", out: PathLike | None = None):
    """The lift model of a campaign (``rtlift identify --static --single-burst [--trains] --train``):
    an identification result whose ``.model`` carries its observer settings (Q, R tuned on the
    training record) and whose ``.provenance``/``.metrics`` are what the model file stores;
    written to ``out`` when given. The structure is ``structure`` if given, else the interaction
    structure when ``trains`` are given and the paper's hybrid when not
    (:func:`rtlift.identify.choice.choose_structure`; ``provenance.structure.choice`` says why)."""
    from rtlift.identify.campaign import IdentifyOptions
    from rtlift.identify.choice import choose_structure, identify_lift
    from rtlift.identify.interaction import InteractionOptions
    from rtlift.observer import tune_observer

    if structure is not None and structure not in LIFT_STRUCTURES:
        raise UserError(f"structure {structure!r}: a lift campaign takes {' or '.join(LIFT_STRUCTURES)}")
    if order is not None and not 1 <= order <= 8:
        raise UserError(f"--order {order}: must be between 1 and 8")
    if dead_time is not None and not 0 <= dead_time <= 80:
        raise UserError(f"--dead-time {dead_time}: must be between 0 and 80 samples")
    files = {"static": static, "single_burst": single_burst, "trains": list(trains), "train": train}
    static, single_burst = _lift(static, 50), _lift(single_burst, 50)
    train = _lift(train, 200)
    trains = [_lift(r, 200) for r in trains]
    names = ", ".join(str(f) for f in (files["static"], files["single_burst"], *files["trains"], files["train"]))
    try:
        choice = choose_structure(trains, structure)
    except ValueError as exc:
        raise UserError(f"cannot identify from {names}: {exc}") from None
    if choice.name == "interaction" and envelope != "recorded":
        raise UserError(f"--envelope {envelope}: the interaction structure's Wiener input is its own "
                        "delivered_envelope stage; --structure paper takes --envelope")
    if choice.name == "interaction" and phi != "auto":
        how = "--structure interaction" if structure else "the interaction structure (chosen for the --trains)"
        raise UserError(f"--phi: not a choice of {how}: its burst part's gains are fitted instead; "
                        "--structure paper fits the paper's hybrid")
    try:
        idf, choice = identify_lift(
            static, single_burst, trains, train, structure,
            hybrid=IdentifyOptions(order=order, form=form, phi=phi, dead_time=dead_time, kernel=kernel,
                                   envelope=envelope),
            interaction=InteractionOptions(order=order, dead_time=dead_time,
                                           form="input_gain" if form == "auto" else form, kernel=kernel))
    except ValueError as exc:
        raise UserError(f"cannot identify from {names}: {exc}") from None
    observer = {**idf.observer, **tune_observer(idf.model, [train])}   # Q, R from the data, for rtlift observe
    require_finite("observer tuning", train.name, observer=observer)
    idf.model.observer_config = observer
    from rtlift.observer.monitor_print import monitor_print  # the live monitor's thresholds, from these records
    from rtlift.residual.fingerprint import FINGERPRINT_START_S

    idf.model.fingerprint["monitor"] = monitor_print(idf.model, [train, static, single_burst],
                                                     int(round(FINGERPRINT_START_S * idf.model.fs_hz)))
    if all(isinstance(f, (str, os.PathLike)) for f in (files["static"], files["single_burst"], files["train"])):
        idf.provenance["files"] = {k: [str(f) for f in v] if k == "trains" else str(v) for k, v in files.items()
                                   if k != "trains" or v}
    if out is not None:
        from rtlift.model.modelfile import save_model

        try:   # no clock in the file: the same inputs give the same bytes
            save_model(idf.model, out, provenance=idf.provenance, metrics=idf.metrics, observer=observer)
        except OSError as exc:
            raise UserError(f"{out}: cannot write model file ({exc.strerror})") from None
    return idf


def identify_record(record: Any, *, structure: str = "wiener", order: int | None = None,
                    out: PathLike | None = None):
    """A single-input model of one generic ``t,u,y`` record (``rtlift identify --record``), or of
    several given as a list (``--record A --record B``: each its own run from rest, one cost), its
    ``.metrics`` holding the held-out and training RMSE; written to ``out`` when given."""
    from rtlift.model.siso_file import save_siso_model
    from rtlift.sysid.identify import MIN_FIT, MIN_HELD, identify_siso

    if structure not in GENERIC_STRUCTURES:
        raise UserError(f"structure {structure!r}: a generic record takes {', '.join(GENERIC_STRUCTURES)}")
    if order is not None and not 1 <= order <= 8:
        raise UserError(f"--order {order}: must be between 1 and 8")
    given = list(record) if isinstance(record, (list, tuple)) else [record]
    recs = [_generic(r, MIN_FIT + MIN_HELD) for r in given]
    try:
        model = identify_siso(recs[0] if len(recs) == 1 else recs, structure, order)
    except ValueError as exc:
        names = ", ".join(str(r) if isinstance(r, (str, os.PathLike)) else rec.name
                          for r, rec in zip(given, recs, strict=True))
        raise UserError(f"cannot identify from {names}: {exc}") from None
    if out is not None:
        try:
            save_siso_model(model, out)
        except OSError as exc:
            raise UserError(f"{out}: cannot write model file ({exc.strerror})") from None
    return model


def read_records(records: Sequence[Any], model: Any, min_samples: int = 2) -> list:
    """The records (paths read, objects as given) of the kind ``model`` takes, at its rate, with
    distinct names (one-line :class:`UserError` otherwise): the check a diagnosis's records pass
    too (:func:`rtlift.diagnose.sources.read_all`)."""
    from rtlift.diagnose.sources import read_all

    return read_all(list(records), model, is_generic(model), min_samples)


def validate(model: Any, records: Sequence[Any], *, skip: int = 0, figures: PathLike | None = None,
             init_state: bool = False) -> list:
    """ρ, NRMSE and RMSE of ``model`` on each record (``rtlift validate``): the model runs from
    rest over the whole record (a generic model with ``init_state``: from the state estimated on
    the ``skip`` unscored samples, :mod:`rtlift.sysid.initial`), scored from sample ``skip``; one
    :class:`~rtlift.model.validation.RecordValidation` per record (``.name``, ``.scores``,
    ``.output``), and one figure per record into ``figures`` when given."""
    from rtlift.model.validation import (
        RecordValidation,
        plot_generic_validation,
        plot_validation,
        validate_record,
    )

    model = load(model)
    generic = is_generic(model)
    if skip < 0:
        raise UserError(f"--skip {skip}: must be 0 or more")
    _check_init_state(init_state, generic, skip)
    recs = read_records(records, model, skip + 2)
    if generic:
        from rtlift.sysid.diagnose import predict, record_scores

        init = skip if init_state else 0
        results = [RecordValidation(r.name, record_scores(model, r, skip, init_state), predict(model, r, init))
                   for r in recs]
    else:
        results = [validate_record(model, r, skip) for r in recs]
    if figures is not None:
        try:
            os.makedirs(figures, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{figures}: cannot create figure directory ({exc.strerror})") from None
        for rec, res in zip(recs, results, strict=True):
            path = Path(figures) / f"{rec.name}.png"
            if generic:
                plot_generic_validation(rec, res, path, skip)
            else:
                plot_validation(rec, res, path)
    return results


def _check_init_state(init_state: bool, generic: bool, skip: int) -> None:
    """``--init-state`` estimates a generic model's state on the ``skip`` unscored samples."""
    if init_state and not (generic and skip > 0):
        raise UserError("--init-state needs a generic (t,u,y) model and --skip N > 0 (the samples it is "
                        "estimated on)")


def diagnose(model: Any, train: Any, validate: Sequence[Any], *, out: PathLike | None = None, skip: int = 0,
             score_from: Sequence[int] | None = None, init_state: bool = False,
             suspect: str | None = None) -> tuple[dict[str, Any], Any]:
    """What ``model`` misses (``rtlift diagnose --train --validate``): candidate effects (a lift
    model) or structures (a generic model) fitted on ``train`` and judged on ``validate``.
    Returns ``(report, augmented_model)``; the report has INTERFACES.md's keys (``baseline``,
    ``augmented``, ``effects``, ``unexplained`` …; the same keys for both kinds). With ``out``:
    ``report.json``, ``report.md`` with figures, ``residual_tests.json`` and
    ``model_augmented.json`` written there. ``skip``: generic records' unscored first samples;
    ``score_from``: per validation record, the first scored sample; ``init_state`` (generic models,
    ``--init-state``): every model runs over a record from the state estimated on its ``skip``
    unscored samples, not from rest. ``suspect`` (a lift model, ``--suspect``): an effect another source of
    evidence names, first among explanations that fit alike (``DiagnoseOptions.suspect``). The records
    are checked as the command checks them (:mod:`rtlift.diagnose.sources`: their kind, rate, length, stems)."""
    from rtlift.diagnose.sources import records

    name = str(model) if isinstance(model, (str, os.PathLike)) else None
    model = load(model)
    src = records(train, list(validate), model, is_generic(model), skip, name)
    if score_from is not None:
        src.score_from = list(score_from)
    return _diagnose(model, src, out, skip, init_state, suspect)


def diagnose_run(model: Any, record: Any, *, split: float | None = None, out: PathLike | None = None,
                 skip: int = 0, init_state: bool = False, suspect: str | None = None) -> tuple[dict[str, Any], Any]:
    """:func:`diagnose` of one long record (``rtlift diagnose --run [--split]``): fitted on its
    first ``split`` (default 0.6), judged on the rest — every model run over the whole record
    from rest and scored from the split on. The report's records are ``<stem>_train`` and
    ``<stem>_validate``, and its ``split`` says where the run was cut."""
    from rtlift.diagnose.sources import run

    name = str(model) if isinstance(model, (str, os.PathLike)) else None
    model = load(model)
    return _diagnose(model, run(record, model, is_generic(model), split, skip, name), out, skip, init_state,
                     suspect)


def _diagnose(model: Any, src: Any, out: PathLike | None, skip: int,
              init_state: bool = False, suspect: str | None = None) -> tuple[dict[str, Any], Any]:
    """The diagnosis of either kind on the records of ``src`` (:class:`rtlift.diagnose.sources.Sources`)."""
    from rtlift.diagnose.report import write
    from rtlift.effects import EFFECT_NAMES

    _check_init_state(init_state, is_generic(model), skip)
    if suspect is not None and (is_generic(model) or suspect not in EFFECT_NAMES):
        raise UserError(f"--suspect {suspect}: one of a lift model's effects ({', '.join(EFFECT_NAMES)})")

    if out is not None:
        try:
            os.makedirs(out, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{out}: cannot create output directory ({exc.strerror})") from None
    if is_generic(model):
        from rtlift.sysid.diagnose import diagnose_generic

        diag = diagnose_generic(model, src.train, src.validate, skip, validate_skip=src.score_from,
                                init_state=init_state)
    else:
        from rtlift.diagnose import DiagnoseOptions
        from rtlift.diagnose import diagnose as diagnose_lift

        diag = diagnose_lift(model, src.train, src.validate, DiagnoseOptions(suspect=suspect), src.score_from)
    if src.split is not None:
        diag.report["split"] = src.split
        diag.report["scoring"] += f"; one run split at sample {src.split['train_samples'][1]}: {src.split['how']}"
    if out is not None:
        write(diag, str(out), src.provenance)
    return diag.report, diag.augmented
