"""Error types. User mistakes are :class:`DataError` (the CLI prints one line and exits 2);
numerical trouble is :class:`NumericalError` (reported, never returned as a silent result)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["ConfigError", "DataError", "NumericalError", "SupportnetError"]


class SupportnetError(Exception):
    """Base class of every error supportnet raises on purpose."""


class DataError(SupportnetError):
    """Input data that cannot be used: a missing or corrupt file, a wrong layout, bad values.

    The message always starts with the offending path, so one line tells the user what to fix.
    """

    def __init__(self, path: str | Path, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class ConfigError(DataError):
    """A config file, option or value that cannot be used: a file that does not parse, an unknown
    key, a value out of range. A kind of :class:`DataError` (it names its file or option first)."""


class NumericalError(SupportnetError):
    """A computation that cannot give a trustworthy answer (degenerate motion, too few
    correspondences, a non-finite cost)."""
