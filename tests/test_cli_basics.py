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


def test_help_lists_each_subcommand_by_name_with_its_description():
    import pkgutil
    import re

    import rtlift.app.commands
    from rtlift.app.cli import COMMANDS

    modules = {m.name for m in pkgutil.iter_modules(rtlift.app.commands.__path__)}
    assert modules == set(COMMANDS)                     # every command module is offered, none forgotten
    r = run("--help")
    assert r.returncode == 0 and not r.stderr
    listed = set(re.findall(r"^    (\w+)  +\S", r.stdout, re.M))
    assert listed == set(COMMANDS)
    assert ":mod:" not in r.stdout and "``" not in r.stdout


def test_a_subcommand_that_fails_to_import_is_a_one_line_error_not_silence(monkeypatch, capsys):
    import sys

    from rtlift.app.cli import main

    monkeypatch.setitem(sys.modules, "rtlift.app.commands.validate", None)   # import raises ImportError
    assert main(["identify", "--help"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'validate' command failed to load" in err and "Traceback" not in err


def test_demo_with_a_bad_effect_spec_is_a_one_line_error_before_any_work(tmp_path):
    r = run("demo", "--out", str(tmp_path / "d"), "--effect", "teleport:x=1")
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "teleport" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "d").exists()
