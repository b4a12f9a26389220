"""Import modules in a background thread, ahead of their first use.

Why: a diagnosis spends seconds with its main thread waiting for the simulator (Warp releases
the GIL while a CPU kernel runs or a GPU sync waits), while scipy and matplotlib, needed later
for the fit and the PNG, cost ~0.5–1 s each to import. Importing them meanwhile hides that.
One worker thread imports the requested modules first come, first served (so the ones needed
soonest should be asked for first). Python's per-module import locks make this safe: a
main-thread import of a module the worker is still loading waits for it. Errors are left to the
main thread's own import to report.
"""
from __future__ import annotations

import importlib
import sys
import threading
from collections import deque

_lock = threading.Lock()
_queue: deque[str] = deque()
_asked: set[str] = set()
_worker: threading.Thread | None = None


def prefetch(*names: str) -> None:
    """Queue `names` (dotted module names) for import in the background worker (started on demand)."""
    global _worker
    with _lock:
        for name in names:
            if name not in sys.modules and name not in _asked:
                _asked.add(name)
                _queue.append(name)
        if _queue and _worker is None:
            _worker = threading.Thread(target=_work, name="pixie-prefetch", daemon=True)
            _worker.start()


def _work() -> None:
    global _worker
    while True:
        with _lock:
            if not _queue:
                _worker = None
                return
            name = _queue.popleft()
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - the main thread's own import raises it where it matters
            pass


def wait(timeout_s: float | None = None) -> bool:
    """Block until the queue is done (tests); True when nothing is left to import."""
    with _lock:
        worker = _worker
    if worker is not None:
        worker.join(timeout_s)
    with _lock:
        return _worker is None and not _queue
