"""The records a diagnosis is given, for either model kind: a training record and validation
records, or one long run split in two (``rtlift diagnose --run``, :func:`rtlift.api.diagnose_run`).

A run is fitted on its first part and judged on the rest: the validation part is the whole run,
every model run over it from rest and scored from the split on, so its state there is the one
the run led to. Records of the other kind, records that share a stem and records at another rate
than the model's are one-line :class:`~rtlift.core.errors.UserError` s.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

from rtlift.core.errors import UserError
from rtlift.core.records import Record, SisoRecord, join_runs, read_record, read_siso_record, record_kind
from rtlift.core.split import MIN_TRAIN_S, MIN_VALIDATE_S, SPLIT_DEFAULT

MIN_PART = 50
"""A generic record's least samples past ``skip``, and each part of a generic run's."""


@dataclass
class Sources:
    """What :func:`rtlift.api.diagnose` is given: the records, per validation record its first
    scored sample (``None``: from ``skip``), how a run was split (``None``: not a run), and where
    the records came from (a lift model file's ``provenance.diagnose``)."""

    train: Record | SisoRecord
    validate: list[Record | SisoRecord]
    score_from: list[int] | None = None
    split: dict[str, Any] | None = None
    provenance: dict[str, Any] = field(default_factory=dict)


def _path(x: Any) -> bool:
    return isinstance(x, (str, os.PathLike))


def read(record: Any, model: Any, generic: bool, min_samples: int, model_name: str | None = None):
    """``record`` (a path read, an object as given) of the kind ``model`` takes, at its rate
    (``model_name``: the model's path, for the messages)."""
    model_name = model_name or "the model"
    if _path(record):
        kind = record_kind(record) if os.path.isfile(record) else None
        if kind is not None and (kind == "siso") != generic:
            raise UserError(f"{record}: a lift record, but {model_name} is a generic (t,u,y) model" if generic else
                            f"{record}: a generic (t,u,y) record, but {model_name} is a lift model")
        record = (read_siso_record if generic else read_record)(record, min_samples=min_samples)
    if abs(record.fs_hz - model.fs_hz) > 1e-6 * model.fs_hz:
        raise UserError(f"{record.name}: sampled at {record.fs_hz:g} Hz, the model at {model.fs_hz:g} Hz")
    return record


def least_samples(model: Any, generic: bool, skip: int = 0) -> int:
    """The fewest samples a record may hold: 12 s of a lift record, ``skip`` + 50 of a generic one."""
    return skip + MIN_PART if generic else int(MIN_TRAIN_S * model.fs_hz)


def _provenance(model_name: str | None, **sources: Any) -> dict[str, Any]:
    """Where the records came from: paths as given, a record given as an object by its name."""
    label = lambda x: str(x) if _path(x) else x.name          # noqa: E731
    out = {} if model_name is None else {"model": model_name}
    return out | {k: [label(x) for x in v] if isinstance(v, list) else v if k == "split" else label(v)
                  for k, v in sources.items()}


def read_all(records: list[Any], model: Any, generic: bool, min_samples: int,
             model_name: str | None = None) -> list[Record | SisoRecord]:
    """Each record :func:`read` (the one check of a record a command is given: its kind, rate and
    length), and their stems distinct (the results are keyed by stem)."""
    recs = [read(r, model, generic, min_samples, model_name) for r in records]
    names = [r.name for r in recs]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise UserError(f"two records share the stem {sorted(dup)[0]!r}; the results are keyed by stem")
    return recs


def records(train: Any, validate: list[Any], model: Any, generic: bool, skip: int = 0,
            model_name: str | None = None) -> Sources:
    """A training record and validation records (``rtlift diagnose --train --validate``); ``train``
    may be a list of records of a generic model's system, each its own run from rest, joined
    (:func:`join_runs`)."""
    trains = list(train) if isinstance(train, (list, tuple)) else [train]
    if len(trains) > 1 and not generic:
        raise UserError(f"{model_name or 'the model'} is a lift model: its effects are fitted on one --train record "
                        "(several are taken for a generic t,u,y model)")
    if not trains:
        raise UserError("give at least one --train record")
    given = read_all([*trains, *validate], model, generic, least_samples(model, generic, skip), model_name)
    train_recs, recs = given[:len(trains)], given[len(trains):]
    train_rec = train_recs[0] if len(trains) == 1 else join_runs(train_recs)
    return Sources(train_rec, recs, provenance=_provenance(model_name, train=train, validate=list(validate)))


def split_index(n: int, fs: float, fraction: float, path: str) -> int:
    """The first validation sample of a lift run of ``n`` samples; a one-line error where either
    part would be too short (:data:`MIN_TRAIN_S`, :data:`MIN_VALIDATE_S`)."""
    k = int(round(fraction * n))
    need_train, need_val = int(MIN_TRAIN_S * fs), int(MIN_VALIDATE_S * fs)
    if k < need_train or n - k < need_val:
        raise UserError(f"{path}: {n / fs:.1f} s split at {fraction:g} leaves {k / fs:.1f} s to fit and "
                        f"{(n - k) / fs:.1f} s to judge; at least {MIN_TRAIN_S:g} s and {MIN_VALIDATE_S:g} s needed")
    return k


def run(record: Any, model: Any, generic: bool, fraction: float | None = None, skip: int = 0,
        model_name: str | None = None) -> Sources:
    """One long record split at ``fraction`` (default :data:`SPLIT_DEFAULT`): fitted on its first
    part (``<stem>_train``), judged on the rest (``<stem>_validate``, the whole run scored from the
    split on); the split as the report records it."""
    fraction = SPLIT_DEFAULT if fraction is None else fraction
    if not 0.0 < fraction < 1.0:
        raise UserError(f"--split {fraction:g}: a fraction of the run between 0 and 1")
    whole = read(record, model, generic, skip + 2 * MIN_PART if generic else least_samples(model, False),
                 model_name)
    n, fs, stem = len(whole), model.fs_hz, whole.name
    where = str(record) if _path(record) else stem
    if generic:
        k = int(round(fraction * n))
        if k < skip + MIN_PART or n - k < MIN_PART:
            raise UserError(f"{where}: {n} samples split at {fraction:g} leave {k} to fit (--skip {skip}) and "
                            f"{n - k} to judge; at least {MIN_PART} each needed")
        train = SisoRecord(whole.t[:k], whole.u[:k], whole.y[:k], dict(whole.meta), f"{stem}_train")
        validate = SisoRecord(whole.t, whole.u, whole.y, dict(whole.meta), f"{stem}_validate")
        how = (f"structure fitted on samples 0..{k - 1}; every model runs over the whole record "
               f"from rest and is scored on samples {k}..{n - 1}")
    else:
        k = split_index(n, fs, fraction, where)
        train, validate = whole.slice(0, k), whole.slice(0, n)
        train.name, validate.name = f"{stem}_train", f"{stem}_validate"
        how = (f"effects fitted on samples 0..{k - 1} ({stem}_train); every model is run over "
               f"the whole record from rest and scored on samples {k}..{n - 1} "
               f"({stem}_validate), so its state at the split is the one the run led to")
    split = {"record": where, "fraction": fraction, "samples": n, "train_samples": [0, k],
             "validate_samples": [k, n], "train_seconds": k / fs, "validate_seconds": (n - k) / fs, "how": how}
    return Sources(train, [validate], [k], split, _provenance(model_name, run=record, split=fraction))
