"""The live view: a page on loopback that plots the observer while the loop runs (``--view``)."""

from rtlift.app.view.arguments import add_view_argument, start_view
from rtlift.app.view.server import DEFAULT_PORT, LiveView

__all__ = ["DEFAULT_PORT", "LiveView", "add_view_argument", "start_view"]
