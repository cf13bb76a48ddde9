"""The README's two set-up commands, in order, in a fresh virtual environment (issue 26).

``python3 -m pip install . && rtlift demo``, then ``python3 -m pip install -e '.[test]' &&
python3 -m pytest``: the editable install uninstalls the first one. The demo runs here, from the
installed wheel with an empty compile cache as a new user runs it, and its report and numbers
are checked (:func:`tests.test_demo_e2e.check_demo`; the suite's only demo run, ~3–4 min). numba used to write its
compiled cache into ``site-packages/rtlift/*/__pycache__``; those files are not the wheel's, so
the uninstall left them, and the orphan ``site-packages/rtlift/`` directory shadowed the
editable package for every later command run outside the checkout (``No module named
'rtlift.blocks.convolution'``). Here the same two installs run in a venv made with the
machine's packages (``--system-site-packages``: nothing but the build backend is fetched),
each followed by a command that compiles and loads a model (``rtlift validate``, the same
compiled functions as the demo and the tests, in seconds rather than minutes), run from a
directory outside the checkout.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_demo_e2e import LIVE_SECONDS, check_demo

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "tests" / "data" / "bench_model.json"

pytestmark = [pytest.mark.slow, pytest.mark.pty]   # the demo serves the bench on ptys


def _copy_checkout(dest: Path) -> Path:
    """The tracked files of the checkout (what a clone has), without build leftovers."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
    for name in files.decode().split("\0"):
        if name and (REPO / name).is_file():
            target = dest / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, target)
    return dest


def test_the_readme_commands_in_order_then_a_model_command_from_another_directory(tmp_path):
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("needs the git checkout to copy the tracked files")
    src = _copy_checkout(tmp_path / "checkout")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True)
    py, rtlift = venv / "bin" / "python", venv / "bin" / "rtlift"
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH", "VIRTUAL_ENV")}
    env.update(XDG_CACHE_HOME=str(tmp_path / "cache-home"), PATH=f"{venv / 'bin'}{os.pathsep}{env['PATH']}")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    record = elsewhere / "sine_k025.csv"

    def run(*argv, cwd=elsewhere):
        r = subprocess.run([str(a) for a in argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, (argv, r.stdout[-1500:], r.stderr[-1500:])
        return r.stdout

    site = Path(run(py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])").strip())

    run(py, "-m", "pip", "install", "-q", ".", cwd=src)                            # README, first command
    demo = elsewhere / "rtlift-demo"                                               # ... && rtlift demo
    r = subprocess.run([str(rtlift), "demo", "--out", str(demo), "--live-seconds", str(LIVE_SECONDS), "--quiet"],
                       cwd=elsewhere, env=env, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-2000:]
    check_demo(demo, r.stdout, r.stderr)
    run(rtlift, "bench", "record", "sine_k025", "--seed", "3", "--out", record)
    first = run(rtlift, "validate", "--model", MODEL, record)
    installed = site / "rtlift"
    assert installed.is_dir() and not any(installed.rglob("*.nb[ic]")), "compiled cache inside the package"
    assert any((tmp_path / "cache-home" / "rtlift" / "numba").rglob("*.nbc"))

    run(py, "-m", "pip", "install", "-q", "-e", ".[test]", cwd=src)               # README, second command
    assert not installed.exists(), sorted(str(p) for p in installed.rglob("*"))[:5]
    second = run(rtlift, "validate", "--model", MODEL, record)
    where = run(py, "-c", "import rtlift.blocks.convolution as m; print(m.__file__)").strip()
    assert where == str(src / "rtlift" / "blocks" / "convolution.py")
    assert first == second and "sine_k025" in second
