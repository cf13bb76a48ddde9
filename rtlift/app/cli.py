"""The ``rtlift`` command line: one module per subcommand under ``rtlift.app.commands``.

Each command module exposes ``register(subparsers)``, which adds its parser and sets
``func`` to a callable ``func(args) -> int``. Exit status: 0 success, 2 bad input
(:class:`~rtlift.core.errors.UserError`, printed as one line), 1 internal failure (one line;
set ``RTLIFT_DEBUG=1`` for the traceback; also a subcommand that fails to import), 130 on Ctrl-C.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback

from rtlift.core.errors import NumericalError, UserError

COMMANDS = ("demo", "bench", "record", "identify", "validate", "diagnose", "observe", "control", "design", "replay",
            "data", "export", "plot")

DESCRIPTION = ("Real-time lift estimation for a stalled wing with burst actuation: record experiments, "
               "identify a model, validate and diagnose it, and run the 400 Hz Kalman observer or the "
               "lift controller live on a serial or CAN link (or on the simulated bench).")
EPILOG = "Run 'rtlift COMMAND --help' for a command's options."


class CommandLoadError(Exception):
    """A subcommand's module failed to import: a broken install or a bug, never skipped silently."""


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="rtlift", description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"rtlift.app.commands.{name}")
        except Exception as exc:  # noqa: BLE001 - named in one line by main()
            raise CommandLoadError(f"the '{name}' command failed to load ({type(exc).__name__}: {exc}); "
                                   f"the installation is broken or incomplete") from exc
        module.register(sub)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"rtlift {version('rtlift')}"
    except PackageNotFoundError:
        return "rtlift (not installed)"


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()
    except CommandLoadError as exc:
        if os.environ.get("RTLIFT_DEBUG"):
            traceback.print_exc()
        print(f"rtlift: error: {exc}", file=sys.stderr)
        return 1
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"rtlift: error: {exc}", file=sys.stderr)
        return 2
    except NumericalError as exc:
        print(f"rtlift: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("rtlift: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1
    except Exception as exc:  # noqa: BLE001 - the one place that turns a bug into exit 1
        if os.environ.get("RTLIFT_DEBUG"):
            traceback.print_exc()
        where = traceback.extract_tb(exc.__traceback__)[-1]
        print(f"rtlift: internal error: {type(exc).__name__}: {exc} "
              f"({os.path.basename(where.filename)}:{where.lineno}; RTLIFT_DEBUG=1 shows the traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
