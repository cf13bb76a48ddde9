"""``rtlift bench record`` and the ``bench serve`` parser (INTERFACES.md, "Command line")."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from rtlift.app.cli import build_parser, main
from rtlift.core.records import read_record


def test_record_sine_k0125_writes_a_valid_record(tmp_path):
    """(Its time is measured by ``benchmarks/pacing.py``, ``bench_record_*``.)"""
    out = tmp_path / "x.csv"
    done = subprocess.run([sys.executable, "-m", "rtlift", "bench", "record", "sine_k0125",
                           "--out", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    rec = read_record(out)
    assert rec.meta["experiment"] == "sine_k0125" and rec.fs_hz == 400.0
    assert rec.meta["seed"] == "0" and rec.meta["effects"] == "none"
    assert len(rec) == 17220 and "dcl_true" in rec.extra
    assert np.corrcoef(rec.dcl, rec.extra["dcl_true"])[0, 1] > 0.99


def test_record_with_effects_and_seed(tmp_path, capsys):
    out = tmp_path / "d.csv"
    assert main(["bench", "record", "train_T7", "--out", str(out), "--seed", "9",
                 "--effect", "delay:seconds=0.05", "--effect", "zero_drift"]) == 0
    rec = read_record(out)
    assert rec.meta["seed"] == "9"
    assert rec.meta["effects"] == "delay:seconds=0.05; zero_drift:rate_per_s=0.0004"
    assert "train_T7" in capsys.readouterr().out


@pytest.mark.parametrize("argv,message", [
    (["bench", "record", "sine", "--out", "{tmp}/a.csv"], "unknown experiment"),
    (["bench", "record", "static", "--out", "{tmp}/a.csv", "--effect", "delay:s=1"],
     "unknown parameter"),
    (["bench", "record", "static", "--out", "{tmp}/missing/a.csv"], "cannot write"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, argv, message):
    code = main([a.replace("{tmp}", str(tmp_path)) for a in argv])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and err.count("\n") == 1


def test_serve_needs_exactly_one_of_serial_or_slcan():
    parser = build_parser()
    args = parser.parse_args(["bench", "serve", "--slcan", "--effect", "delay", "--seed", "3"])
    assert args.slcan and not args.serial and args.effect == ["delay"] and args.seed == 3
    assert args.experiment == "random" and args.fault == []
    for argv in (["bench", "serve"], ["bench", "serve", "--serial", "--slcan"]):
        with pytest.raises(SystemExit) as info:
            parser.parse_args(argv)
        assert info.value.code == 2
