"""``rtlift data list`` / ``rtlift data export NAME --out DIR``: the vendored benchmarks' official
splits as ``t,u,y`` records that read back equal to the ``.npz`` arrays they were cut from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtlift.app.cli import main
from rtlift.core.records import read_siso_record

DATA = Path(__file__).resolve().parents[1] / "rtlift" / "data" / "benchmarks"


def exported(name: str, out: Path) -> tuple:
    assert main(["data", "export", name, "--out", str(out)]) == 0
    return read_siso_record(out / f"{name}_estimation.csv"), read_siso_record(out / f"{name}_test.csv")


def test_cascaded_tanks_records_equal_the_npz_estimation_and_test_arrays(tmp_path, capsys):
    est, test = exported("cascaded_tanks", tmp_path)
    d = np.load(DATA / "cascaded_tanks.npz")
    for rec, u, y in ((est, d["u_est"], d["y_est"]), (test, d["u_test"], d["y_test"])):
        np.testing.assert_array_equal(rec.u, u)
        np.testing.assert_array_equal(rec.y, y)
        assert rec.fs_hz == pytest.approx(1.0 / float(d["Ts"]), rel=1e-12)
        np.testing.assert_allclose(rec.t, np.arange(u.size) * float(d["Ts"]), rtol=1e-12)
    assert (est.meta["benchmark"], est.meta["split"], test.meta["split"]) == ("cascaded_tanks", "estimation", "test")
    assert capsys.readouterr().out.count("wrote ") == 2


def test_wh2009_splits_follow_the_official_slice(tmp_path):
    est, test = exported("wh2009", tmp_path)
    d = np.load(DATA / "wh2009.npz")
    lo, hi = (int(v) for v in d["official_slice"])
    n = int(d["n_train"])
    assert (len(est), len(test)) == (n, hi - lo - n) == (100_000, 78_800)
    np.testing.assert_array_equal(est.u, d["u"][lo:lo + n])
    np.testing.assert_array_equal(est.y, d["y"][lo:lo + n])
    np.testing.assert_array_equal(test.u, d["u"][lo + n:hi])
    np.testing.assert_array_equal(test.y, d["y"][lo + n:hi])
    assert test.fs_hz == float(d["fs"]) == 51200.0


def test_list_names_every_benchmark_and_a_bad_name_is_one_line(tmp_path, capsys):
    assert main(["data", "list"]) == 0
    out = capsys.readouterr().out
    for name, n_est, n_test in (("wh2009", 100000, 78800), ("silverbox", 65062, 40475),
                                ("cascaded_tanks", 1024, 1024)):
        row = next(line.split() for line in out.splitlines() if line.startswith(name + " "))
        assert row[2:4] == [str(n_est), str(n_test)]
    assert main(["data", "export", "silver", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "silverbox" in err and not (tmp_path / "x").exists()


def test_list_from_a_missing_folder_is_one_line_and_no_header(tmp_path, capsys):
    """Before: the table's header was printed, then the error."""
    assert main(["data", "list", "--data", str(tmp_path / "nonexistent")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "not found" in err
