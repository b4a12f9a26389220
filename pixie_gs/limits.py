"""Resource bounds checked before allocating: memory and disk a step will need vs what the machine has.

A request that cannot fit is refused up front with a one-line InputError that states the figure,
instead of a MemoryError, an OOM kill or a full disk half-way through a run.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from .errors import InputError


def format_bytes(n: float) -> str:
    """`n` bytes as a short human figure (e.g. '7.9 GB', '2.2 TB')."""
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} PB"  # pragma: no cover


def available_memory_bytes() -> int:
    """Memory this process can still use (bytes): MemAvailable on Linux, else physical memory."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 1 << 62


def free_disk_bytes(path: str | Path) -> int:
    """Free bytes on the file system holding `path` (or its nearest existing parent)."""
    p = Path(path).resolve()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return int(shutil.disk_usage(p).free)
    except OSError:
        return 1 << 62


def require_memory(nbytes: float, what: str, path: str | Path | None = None, fraction: float = 0.8) -> None:
    """InputError when `what` needs more than `fraction` of the available memory."""
    have = available_memory_bytes()
    if nbytes > fraction * have:
        raise InputError(f"{what} needs about {format_bytes(nbytes)} of memory, but only "
                         f"{format_bytes(have)} is available", path)


def require_disk(nbytes: float, what: str, path: str | Path, fraction: float = 0.95) -> None:
    """InputError when `what` would write more than `fraction` of the free disk space at `path`."""
    have = free_disk_bytes(path)
    if nbytes > fraction * have:
        raise InputError(f"{what} needs about {format_bytes(nbytes)} of disk, but only "
                         f"{format_bytes(have)} is free there", path)
