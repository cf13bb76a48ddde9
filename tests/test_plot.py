"""``rtlift plot RUN``: the demo's figures of an observe/control run after the fact, from its
estimates CSV or its frame log replayed; a bad file is one line and exit 2."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hil_sim.experiments import run_experiment
from rtlift.app.cli import main
from rtlift.app.live import EstimateWriter
from rtlift.model.modelfile import load_model
from rtlift.observer import Observer

MODEL = Path(__file__).parent / "data" / "bench_model.json"


def _estimates_csv(path: Path, seconds: float = 6.0) -> int:
    """The estimates file ``rtlift observe --out`` writes, for the observer run on a bench record
    (ΔCL empty while taring, as live). Returns its row count."""
    rec = run_experiment("random", seed=3).to_record()
    n = int(seconds * rec.fs_hz)
    out = Observer.from_model(load_model(MODEL)).run(rec.cmu[:n], rec.cmu_envelope[:n], rec.dcl[:n])
    writer = EstimateWriter(path, {"tool": "test"})
    for k in range(n):
        dcl = None if k < 2 * rec.fs_hz else float(rec.dcl[k])
        est = SimpleNamespace(dcl=float(out["dcl"][k]), model_dcl=float(out["model_dcl"][k]),
                              innovation=float(out["innovation"][k]), nis=float(out["nis"][k]),
                              flags=int(out["flags"][k]))
        writer.write(k, k / rec.fs_hz, k, k * 2500, float(rec.cmu[k]), float(rec.cmu_envelope[k]), dcl, est)
    writer.close()
    return n


def _drawn(png: Path) -> float:
    """Share of the image's pixels that are not background white (a blank figure: 0)."""
    import matplotlib.image

    img = matplotlib.image.imread(png)[..., :3]
    return float(np.mean(np.any(img < 0.9, axis=-1)))


def test_an_estimates_csv_gives_the_observer_and_innovation_figures(tmp_path, capsys):
    csv = tmp_path / "run.csv"
    _estimates_csv(csv)
    assert main(["plot", str(csv), "--out", str(tmp_path / "fig")]) == 0
    assert "rtlift plot:" in capsys.readouterr().out
    for name in ("run_observer.png", "run_innovation.png"):
        png = tmp_path / "fig" / name
        assert png.stat().st_size > 20_000
        assert _drawn(png) > 0.03            # axes, traces and labels: a blank canvas has none
    assert not (tmp_path / "fig" / "run_control.png").exists()


@pytest.mark.parametrize("content, says", [
    ("t,cmu,cmu_envelope,dcl\n0,0,0,0\n0.0025,0,0,0\n", "column(s) dcl_hat, model_dcl, innovation, nis missing"),
    ("# only metadata\n", "no header line"),
    ("t,dcl,dcl_hat,model_dcl,innovation,nis\n0,1,2,3,4,x\n0.0025,1,2,3,4,5\n", "not a number"),
    ("t,dcl,dcl_hat,model_dcl,innovation,nis\n0,1,2,3,4,5\n", "1 estimate row(s), at least 2 needed"),
])
def test_a_file_that_is_not_an_estimates_csv_is_one_line_and_exit_2(tmp_path, capsys, content, says):
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    assert main(["plot", str(bad)]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1 and "Traceback" not in err


def test_a_missing_file_a_binary_csv_and_a_log_without_model_are_one_line_each(tmp_path, capsys):
    binary = tmp_path / "frames.csv"
    binary.write_bytes(bytes(range(256)))
    log = tmp_path / "frames.bin"
    log.write_bytes(b"\x00" * 64)
    for argv, says in ((["plot", str(tmp_path / "none.csv")], "none.csv: no such file"),
                       (["plot", str(binary)], "not a text (UTF-8) file"),
                       (["plot", str(log)], "give --model")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1, err


@pytest.mark.slow
@pytest.mark.pty
def test_a_control_log_is_replayed_and_plotted_with_its_reference_and_commands(tmp_path):
    from hil_sim.devices import SerialDaq
    from hil_sim.hil import HilStream

    stream = HilStream("random", seed=5)
    log = tmp_path / "control.bin"
    with SerialDaq(stream) as dev:
        stream.control = dev.control
        proc = subprocess.Popen([sys.executable, "-m", "rtlift", "control", "--serial", dev.path, "--model",
                                 str(MODEL), "--reference", "steps:0.08@0,0.14@1.5", "--seconds", "3", "--kp",
                                 "0.5", "--ti", "0.2", "--log", str(log)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert "link open" in proc.stderr.readline()
        dev.start()
        _, err = proc.communicate(timeout=180)
    assert proc.returncode == 0, err
    run = subprocess.run([sys.executable, "-m", "rtlift", "plot", str(log), "--model", str(MODEL)],
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr
    rmse = re.search(r"tracking RMSE (\S+)$", run.stdout, re.M).group(1)      # replay's line, rounded
    assert len(rmse.lstrip("0.").replace(".", "")) <= 4 and 0 < float(rmse) < 0.1
    for name in ("control_observer.png", "control_innovation.png", "control_control.png"):
        assert _drawn(tmp_path / name) > 0.03
