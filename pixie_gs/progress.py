"""Progress display for long steps: a tqdm bar on stderr, silenced by `--quiet`."""
from __future__ import annotations

import sys
from typing import Iterable, Iterator, TypeVar

from tqdm import tqdm

T = TypeVar("T")

_quiet = False


def set_quiet(quiet: bool) -> None:
    """Silence (or re-enable) every progress bar and stage line of this process."""
    global _quiet
    _quiet = quiet


def is_quiet() -> bool:
    return _quiet


def progress(iterable: Iterable[T], desc: str, total: int | None = None, unit: str = "it") -> Iterator[T]:
    """Wrap `iterable` in a progress bar on stderr (nothing when quiet)."""
    return iter(tqdm(iterable, desc=desc, total=total, unit=unit, disable=_quiet, file=sys.stderr,
                     dynamic_ncols=True, leave=False))


def stage(message: str) -> None:
    """Print one line describing the stage that starts now (stderr, nothing when quiet)."""
    if not _quiet:
        print(f"[pixie] {message}", file=sys.stderr, flush=True)
