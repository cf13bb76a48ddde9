"""``rtlift diagnose`` kept warm in another process, for ``--adapt`` (:mod:`rtlift.app.adapt`).

A window's diagnosis used to start a fresh ``python -m rtlift diagnose`` at each departure: on a
loaded machine the interpreter's start and the imports (numba's caches, scipy, the effect catalog)
took most of its wall time — 25 s of imports alone at a load average of 16 — and a run could end
before its swap. The worker is started (niced) when the loop starts, imports all that while the
loop runs, and then waits: each request is one line on its stdin, the JSON list of ``rtlift``'s
arguments (``["diagnose", "--model", M, "--run", W, ...]``), run by the command line's own
:func:`rtlift.app.cli.main` — the same code, exit statuses and files as the command; its answer
is one line on its stdout, ``{"code": exit status, "stderr": what the command wrote there}``.
The command's own output to stdout is discarded. EOF on stdin ends the worker.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
from typing import Any

WARM = ("rtlift.app.cli", "rtlift.api", "rtlift.diagnose", "rtlift.observer", "rtlift.model.modelfile")
"""Imported before the first request (what a diagnosis imports first)."""


def serve(stdin: Any = None, answers: Any = None) -> int:
    """The worker's loop: one request line in, one answer line out, until EOF."""
    import importlib

    stdin = stdin or sys.stdin
    if answers is None:
        answers = os.fdopen(os.dup(1), "w", encoding="utf-8")
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)              # the command's own prints go nowhere, never into the answers
        sys.stdout = open(os.devnull, "w", encoding="utf-8")  # noqa: SIM115 - for the worker's life
    for name in WARM:
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    from rtlift.app.cli import main

    for line in stdin:
        if not line.strip():
            continue
        err = io.StringIO()
        try:
            argv = [str(a) for a in json.loads(line)]
            with contextlib.redirect_stderr(err):
                code = main(argv)
        except SystemExit as exc:          # argparse on bad arguments
            code = exc.code if isinstance(exc.code, int) else 2
        except Exception as exc:  # noqa: BLE001 - the answer says what failed; the worker serves on
            code = 1
            err.write(f"diagnose worker: {type(exc).__name__}: {exc}\n")
        answers.write(json.dumps({"code": code, "stderr": err.getvalue()}) + "\n")
        answers.flush()
    return 0


class DiagnoseWorker:
    """The client: a worker process started now (``preexec_fn``, e.g. a nice), asked by :meth:`run`
    one request at a time. A worker that died (or never started) is replaced by a fresh one for
    the request, so a request is answered as the command would answer it."""

    def __init__(self, preexec_fn: Any = None) -> None:
        self._preexec = preexec_fn
        self.proc: subprocess.Popen | None = None
        self.closed = False
        self._start()

    def _start(self) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "rtlift.app.diagnose_worker"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                     preexec_fn=self._preexec)

    def run(self, argv: list[str]) -> tuple[int, str]:
        """``rtlift`` ``argv`` in the worker: (exit status, its stderr)."""
        for _ in range(2):
            if self.closed:
                break
            if self.proc is None or self.proc.poll() is not None:
                self._start()
            try:
                self.proc.stdin.write(json.dumps(argv) + "\n")
                self.proc.stdin.flush()
                line = self.proc.stdout.readline()
            except (BrokenPipeError, OSError):
                line = ""
            if line:
                answer = json.loads(line)
                return int(answer["code"]), str(answer["stderr"])
            self._end()
        if self.closed:
            return 1, "the run ended before the window's diagnosis did\n"
        return 1, "diagnose worker: no answer (the worker process ended twice)\n"

    def close(self) -> None:
        """EOF to the worker (it ends after the request in hand, killed after 5 s); no more requests."""
        self.closed = True
        self._end()

    def _end(self) -> None:
        proc, self.proc = self.proc, None
        if proc is None:
            return
        with contextlib.suppress(OSError):
            proc.stdin.close()
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


if __name__ == "__main__":
    sys.exit(serve())
