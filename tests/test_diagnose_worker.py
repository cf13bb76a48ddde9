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
