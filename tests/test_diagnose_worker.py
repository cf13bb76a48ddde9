"""The warm ``rtlift diagnose`` worker of ``--adapt`` (rtlift.app.diagnose_worker): the command's
own answers, one process for several requests, and no request after it is closed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from rtlift.app.diagnose_worker import DiagnoseWorker

MODEL = str(Path(__file__).parent / "data" / "bench_model.json")


def test_the_worker_answers_as_the_command_and_serves_on(tmp_path):
    argv = ["diagnose", "--model", MODEL, "--run", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "d")]
    cli = subprocess.run([sys.executable, "-m", "rtlift", *argv], capture_output=True, text=True)
    worker = DiagnoseWorker()
    try:
        pid = worker.proc.pid
        code, err = worker.run(argv)
        assert (code, err.strip()) == (cli.returncode, cli.stderr.strip())
        assert code == 2 and len(err.strip().splitlines()) == 1 and "missing.csv" in err
        code, err = worker.run(["diagnose", "--model", MODEL])              # argparse's exit, served on
        assert code == 2 and "required: --out" in err
        code, _ = worker.run(argv)
        assert code == 2 and worker.proc.pid == pid                         # the same process throughout
    finally:
        worker.close()
    assert worker.proc is None
    assert worker.run(argv)[0] == 1                                        # closed: no new process
    assert worker.proc is None


def test_a_diagnosis_the_runs_end_cuts_off_is_an_event(tmp_path, monkeypatch):
    """A worker that never answers (here: one that reads its requests and ends at EOF): the run's
    end closes it, and the window's diagnosis is reported as cut off, not silently dropped."""
    import numpy as np

    from rtlift.app.adapt import AFTER_S, BEFORE_S, Adapter
    from rtlift.core.rate import FS_HZ

    def mute(self):
        self.proc = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)

    monkeypatch.setattr(DiagnoseWorker, "_start", mute)

    class Loop:
        monitor = observer = None

    events = []
    ad = Adapter(Loop(), MODEL, tmp_path, events=events.append)
    start = int(BEFORE_S * FS_HZ)
    ad.on_departure({"sample": start + 1, "t_s": start / FS_HZ, "test": "hold", "suspect": "actuator_fade"})
    rng = np.random.default_rng(0)
    for i in range(start + int(AFTER_S * FS_HZ) + 1):
        ad.after_step(i, 0.02, 0.01, 0.1 + 1e-3 * rng.standard_normal())
    assert ad.busy and events == []
    ad.close(0.0)                   # the run's end cuts the diagnosis off at once (no wait)
    assert not ad.busy
    assert len(events) == 1 and events[0]["event"] == "diagnosis" and not events[0].get("swapped")
    assert events[0]["reason"] == "RuntimeError: the run ended before the window's diagnosis did"
    assert events[0]["window_stop"] - events[0]["window_start"] == int((BEFORE_S + AFTER_S) * FS_HZ)
