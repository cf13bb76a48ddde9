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


def _subparsers(parser):
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield name, sub
                yield from ((f"{name} {n}", s) for n, s in _subparsers(sub))


def test_every_help_has_a_whole_description_without_markup_and_names_every_choice():
    from rtlift.app.cli import build_parser

    seen = []
    for name, sub in _subparsers(build_parser()):
        seen.append(name)
        text = sub.format_help()
        assert sub.description, f"rtlift {name} --help has no description"
        assert sub.description.rstrip().endswith((".", ")")), f"rtlift {name}: description cut off"
        assert "``" not in text and ":mod:" not in text and ":class:" not in text, name
        for action in sub._actions:
            for choice in action.choices or ():
                if isinstance(action.choices, dict):
                    continue                                     # subcommands: listed with their own help
                assert str(choice) in (action.help or ""), f"rtlift {name} {action.option_strings}: {choice}"
    assert {"bench record", "bench serve", "identify", "replay"} <= set(seen)
