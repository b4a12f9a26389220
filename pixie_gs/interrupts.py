"""Ctrl-C and SIGTERM that a command cannot lose.

Python runs a signal handler between two bytecodes of the main thread, wherever that is. When it
is inside a finalizer (a `__del__`, such as the one each freed warp array runs, dozens per
simulated frame), the exception the handler raises is printed as "Exception ignored" and dropped:
the run went on and replaced the previous output with its own, exit 0. So the handlers installed
here also record the signal, and `raise_if_interrupted()` raises it again at the points that must
not pass an interrupt by: before an output is committed and once per simulated frame.
`deferred()` holds interrupts over a few statements that must happen together.
"""
from __future__ import annotations

import contextlib
import signal
import sys
import threading
from typing import Iterator


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so every `except BaseException`/`finally` cleanup runs."""


_pending: int | None = None  # the signal received and not yet seen through to the end of the command
_defer_depth = 0  # > 0 inside deferred(): the handler records and returns


def _interruption(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _on_signal(signum: int, frame) -> None:
    global _pending
    _pending = signum
    if _defer_depth == 0:
        raise _interruption(signum)


def pending() -> int | None:
    """The signal number received during this command and not raised to its end yet (None: none)."""
    return _pending


def raise_if_interrupted() -> None:
    """Raise the Ctrl-C/SIGTERM received earlier if its first raise was swallowed (see the module
    docstring); no-op when none came or inside `deferred()`."""
    if _pending is not None and _defer_depth == 0:
        raise _interruption(_pending)


def _quiet_about_swallowed_interrupts(previous_hook):
    """An unraisable-exception hook that says nothing of an interrupt dropped in a finalizer (it is
    raised again later, and the command reports it in one line) and passes anything else on."""
    def hook(unraisable) -> None:
        if not (_pending is not None and isinstance(unraisable.exc_value, KeyboardInterrupt)):
            previous_hook(unraisable)

    return hook


def install() -> tuple | None:
    """Take SIGTERM, and SIGINT unless it is ignored (a background job), for this command; clears any
    earlier record. Returns what `restore` needs, or None off the main thread (handlers cannot be set)."""
    global _pending
    if threading.current_thread() is not threading.main_thread():
        return None
    _pending = None
    previous_term = signal.signal(signal.SIGTERM, _on_signal)
    previous_int = signal.getsignal(signal.SIGINT)
    if previous_int is signal.default_int_handler:
        signal.signal(signal.SIGINT, _on_signal)
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_about_swallowed_interrupts(previous_hook)
    return previous_term, previous_int, previous_hook


def restore(previous: tuple | None) -> None:
    """Put back the handlers `install` replaced, and forget the record."""
    global _pending
    _pending = None
    if previous is None:
        return
    sys.unraisablehook = previous[2]
    with contextlib.suppress(ValueError, TypeError):
        signal.signal(signal.SIGTERM, previous[0])
        if signal.getsignal(signal.SIGINT) in (_on_signal, _record_only, signal.SIG_DFL):
            signal.signal(signal.SIGINT, previous[1])


def _record_only(signum: int, frame) -> None:
    global _pending
    _pending = signum
    signal.signal(signum, signal.SIG_DFL)  # one more of the same ends the process at once (a hung exit)


def stop_raising() -> None:
    """From here on a Ctrl-C/SIGTERM is noted and nothing more: once the command has been interrupted
    or has ended, its clean-up and the interpreter's exit must not be cut by a second signal (Python's
    own handler would print a KeyboardInterrupt traceback, and a half-done clean-up would leave a
    staging folder). The first such signal is noted; the next one of the same kind ends the process at
    once, without Python, as a user pressing Ctrl-C again at a hung exit expects. `restore` puts the
    earlier handlers back for callers that go on."""
    if threading.current_thread() is not threading.main_thread():
        return
    signal.signal(signal.SIGTERM, _record_only)
    if signal.getsignal(signal.SIGINT) in (signal.default_int_handler, _on_signal):
        signal.signal(signal.SIGINT, _record_only)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold Ctrl-C/SIGTERM until the block ends (then raise it as usual), so a step that creates
    something and records it cannot be split by a signal. The handlers above record instead of
    raising inside the block; the thread mask also covers signals with Python's default handlers.
    No-op off the main thread."""
    global _defer_depth
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    mask = hasattr(signal, "pthread_sigmask")
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM}) if mask else None
    _defer_depth += 1
    try:
        yield
    finally:
        _defer_depth -= 1
        if mask:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
    raise_if_interrupted()
