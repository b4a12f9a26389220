"""Errors that the `pixie` command turns into one-line messages and exit codes.

Exit codes: 0 success, 1 bad input (a file or value the user gave), 2 usage (argparse),
3 the computation failed (e.g. a simulation that diverged).
"""
from __future__ import annotations

from pathlib import Path


class PixieError(Exception):
    """A problem the user can fix; printed as one line, never as a traceback."""

    exit_code = 1

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {message}" if self.path else message)


class InputError(PixieError):
    """A bad input file or argument (exit code 1)."""


class ComputationError(PixieError):
    """A computation that could not finish soundly, e.g. a diverging simulation (exit code 3)."""

    exit_code = 3


def require_file(path: str | Path, kind: str) -> Path:
    """`path` as a Path, or InputError when it is missing or a directory (`kind`: e.g. "a .ply file")."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    if path.is_dir():
        raise InputError(f"is a directory, not {kind}", path)
    return path
