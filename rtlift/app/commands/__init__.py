"""Subcommands of ``rtlift``; each module has ``register(subparsers)`` (see :mod:`rtlift.app.cli`)."""
