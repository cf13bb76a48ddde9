"""Reading a live command's stderr as a person does: the line that says a thing, wherever it falls."""

from __future__ import annotations

from typing import IO


def lines_until(stream: IO[str], text: str, most: int = 6) -> list[str]:
    """The next lines of ``stream`` up to and including the first that contains ``text`` (at most
    ``most``); an AssertionError naming the last lines read when none does."""
    seen = []
    for _ in range(most):
        line = stream.readline()
        seen.append(line)
        if text in line or not line:
            break
    assert text in seen[-1], f"no line with {text!r} in {seen[-6:]!r}"
    return seen


def line_with(stream: IO[str], text: str, most: int = 6) -> str:
    """The first of the next ``most`` lines of ``stream`` that contains ``text``; an AssertionError
    naming the lines read when none does (a line a command adds, e.g. which monitor thresholds are
    in force, does not move what a test waits for)."""
    return lines_until(stream, text, most)[-1]
