"""The one place the commands get their rich ``Console``: on a terminal it is as wide as the
terminal; written to a file or a pipe (a log, CI) it is ``COLUMNS`` wide where that is set, else
``LOG_WIDTH``, so tables and long lines are never cut at rich's default of 80 columns."""

from __future__ import annotations

import os

from rich.console import Console

__all__ = ["LOG_WIDTH", "make_console"]

LOG_WIDTH = 200
"""Columns of output that goes to a file or a pipe, where no terminal says how wide to be."""


def make_console(stderr: bool = True) -> Console:
    """A ``Console`` on stderr (progress, tables, messages of a command) or, with
    ``stderr=False``, on stdout (what a command prints as its answer, e.g. ``info``)."""
    out = Console(stderr=stderr)
    if not out.is_terminal and not os.environ.get("COLUMNS", "").strip().isdigit():
        out.width = LOG_WIDTH
    return out
