"""Record files: round trip, and every bad file is a one-line error naming file, line and column."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtlift.core.errors import RecordError
from rtlift.core.records import Record, read_record, write_record

GOOD = ("# experiment: test\n# fs_hz: 400\nt,cmu,cmu_envelope,dcl,volts\n"
        "0,0,0,0.1,0\n0.0025,0.001,0.001,0.2,5\n0.005,0,0.001,0.15,0\n")


def test_round_trip_is_exact(tmp_path, rng):
    n = 500
    rec = Record(np.arange(n) / 400.0, rng.random(n) * 0.02, rng.random(n) * 0.02, rng.normal(size=n) * 0.1,
                 {"experiment": "x", "fs_hz": "400"}, {"dcl_true": rng.normal(size=n)}, "x")
    write_record(tmp_path / "x.csv", rec)
    back = read_record(tmp_path / "x.csv")
    for col in ("t", "cmu", "cmu_envelope", "dcl"):
        np.testing.assert_array_equal(getattr(back, col), getattr(rec, col))
    np.testing.assert_array_equal(back.extra["dcl_true"], rec.extra["dcl_true"])
    assert back.meta == rec.meta and back.name == "x" and back.fs_hz == 400.0


def test_extra_columns_and_metadata_are_kept(tmp_path):
    (tmp_path / "r.csv").write_text(GOOD)
    r = read_record(tmp_path / "r.csv")
    assert r.meta["experiment"] == "test" and list(r.extra) == ["volts"] and len(r) == 3


@pytest.mark.parametrize("text, where", [
    ("t,cmu,dcl\n0,0,0\n", ":1: column 'cmu_envelope' is missing"),
    ("# a: b\nt,cmu,cmu_envelope,dcl\n0,0,0,0\n0.1,x,0,0\n", ":4: column 'cmu': not a number: 'x'"),
    ("t,cmu,cmu_envelope,dcl\n0,0,0,0\n0.1,0,0,nan\n", ":3: column 'dcl': nan is not a finite number"),
    ("t,cmu,cmu_envelope,dcl\n0,0,0,0\n0.1,0,0,0\n0.1,0,0,0\n", ":4: column 't': not strictly increasing"),
    ("t,cmu,cmu_envelope,dcl\n0,0,0,0\n0.1,0,0\n", ":3: 3 cells, the header has 4"),
    ("t,cmu,cmu_envelope,dcl\n0,0,0,0\n", "1 samples, at least 2 needed"),
    ("# only: metadata\n", "no header line"),
])
def test_bad_files_name_file_line_and_column(tmp_path, text, where):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(RecordError) as exc:
        read_record(p)
    assert str(exc.value).startswith(str(p)) and where in str(exc.value) and "\n" not in str(exc.value)


def test_missing_file_is_a_record_error(tmp_path):
    with pytest.raises(RecordError, match="no such file"):
        read_record(tmp_path / "nope.csv")


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=300))
def test_reader_never_raises_anything_but_record_error(tmp_path_factory, text):
    p = tmp_path_factory.mktemp("fuzz") / "f.csv"
    p.write_text("t,cmu,cmu_envelope,dcl\n" + text, encoding="utf-8")
    try:
        r = read_record(p)
    except RecordError as exc:
        assert "\n" not in str(exc)
    else:
        assert len(r) >= 2 and np.all(np.diff(r.t) > 0)
