"""Errors that the `pixie` command turns into one-line messages and exit codes.

Exit codes: 0 success, 1 bad input (a file or value the user gave), 2 usage (argparse),
3 the computation failed (e.g. a simulation that diverged).
"""
from __future__ import annotations

import os
import stat
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
    """`path` as a Path, or InputError when it is missing, a directory or not a regular file
    (a FIFO, socket or device would block or never end; `kind`: e.g. "a .ply file")."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path) from None
    if stat.S_ISDIR(mode):
        raise InputError(f"is a directory, not {kind}", path)
    if not stat.S_ISREG(mode):
        raise InputError(f"is not a regular file (a pipe, socket or device), not {kind}", path)
    if not os.access(path, os.R_OK):
        raise InputError("cannot read (permission denied)", path)
    return path


def require_finite_result(values: dict[str, object], what: str, path: str | Path | None = None) -> None:
    """ComputationError (exit 3) naming the first quantity of `values` (name → array or number)
    that holds NaN or inf: a result that is not finite is never written or reported as success."""
    import numpy as np

    for name, value in values.items():
        arr = np.asarray(value, dtype=np.float64) if not isinstance(value, np.ndarray) else value
        if arr.dtype.kind not in "fc":
            continue
        bad = ~np.isfinite(arr)
        if bad.any():
            first = np.unravel_index(int(np.argmax(bad)), arr.shape) if arr.ndim else ()
            where = f", first at index {first[0] if len(first) == 1 else first}" if arr.ndim else ""
            raise ComputationError(f"{what}: {name} is not finite (NaN/inf) in {int(bad.sum())} "
                                   f"value(s){where}; nothing was written", path)


MAX_JSON_BYTES = 100_000_000  # index files and tables are small; refuse absurd ones before reading


def read_json_file(path: str | Path, kind: str) -> object:
    """Parse a JSON file a user gave (`kind`: e.g. "a dataset index"): one-line InputError for a
    non-regular or huge file, bytes that are not UTF-8, bad JSON, absurd nesting or huge integers."""
    import json

    path = require_file(path, kind)
    size = path.stat().st_size
    if size > MAX_JSON_BYTES:
        raise InputError(f"is {size} bytes; {kind} is at most {MAX_JSON_BYTES}", path)
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text (byte {exc.start}); {kind} is a JSON file", path) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc.msg} at line {exc.lineno})", path) from None
    except RecursionError:
        raise InputError("JSON nested too deeply", path) from None
    except ValueError as exc:  # e.g. an integer literal with thousands of digits
        raise InputError(f"not usable JSON ({str(exc).splitlines()[0][:100]})", path) from None
