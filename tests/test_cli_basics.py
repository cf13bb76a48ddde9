"""Command-line behaviour common to every subcommand: usage errors are one line and exit 2."""

from __future__ import annotations

import subprocess
import sys


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rtlift", *args], capture_output=True, text=True, timeout=120)


def test_unknown_subcommand_is_a_one_line_usage_error():
    r = run("frobnicate")
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "invalid choice" in r.stderr


def test_help_lists_the_subcommands():
    r = run("--help")
    assert r.returncode == 0 and "COMMAND" in r.stdout


def test_demo_with_a_bad_effect_spec_is_a_one_line_error_before_any_work(tmp_path):
    r = run("demo", "--out", str(tmp_path / "d"), "--effect", "teleport:x=1")
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "teleport" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "d").exists()
