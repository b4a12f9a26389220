"""Import modules in a background thread, ahead of their first use.

Why: a diagnosis spends seconds with its main thread waiting for the simulator (Warp releases
the GIL while a CPU kernel runs or a GPU sync waits), while scipy and matplotlib, needed later
for the fit and the PNG, cost ~0.5–1 s each to import. Importing them meanwhile hides that.
Python's per-module import locks make this safe: a main-thread import of a module the helper is
still loading waits for it. Errors are left to the main thread's own import to report.
"""
from __future__ import annotations

import importlib
import sys
import threading


def prefetch(*names: str) -> threading.Thread | None:
    """Start importing `names` (dotted module names) in a daemon thread; None when all are loaded."""
    todo = [n for n in names if n not in sys.modules]
    if not todo:
        return None

    def work() -> None:
        for name in todo:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - the main thread's import raises it where it matters
                pass

    thread = threading.Thread(target=work, name="pixie-prefetch", daemon=True)
    thread.start()
    return thread
