"""Errors of the firmware I/O layer; all are :class:`rtlift.core.errors.UserError` (one line)."""

from __future__ import annotations

from rtlift.core.errors import UserError


class FirmwareIOError(UserError):
    """Something a user can fix about a link or a log (port, interface, file)."""


class LinkError(FirmwareIOError):
    """A link that cannot be opened: missing port, unknown CAN interface, bad configuration."""


class LogError(FirmwareIOError):
    """A log file that cannot be written or read (unknown extension, unreadable file)."""
