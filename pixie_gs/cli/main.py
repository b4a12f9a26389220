"""Entry point of the `pixie` command.

Each subcommand lives in `pixie_gs/cli/cmd_<name>.py` and exposes
`add_parser(subparsers, parents) -> argparse.ArgumentParser` (which sets `func=run`).
Command modules import heavy libraries (torch, warp) inside `run`, so `--help` stays fast.
Exit codes: 0 ok, 1 bad input, 2 usage, 3 computation failed, 130 interrupted.
"""
from __future__ import annotations

import argparse
import atexit
import contextlib
import gc
import importlib
import signal
import sys
from typing import Iterator

from .. import interrupts
from ..devices import thread_defaults
from ..errors import PixieError
from ..progress import set_quiet

COMMANDS = ["demo", "info", "convert", "generate", "train", "evaluate", "prepare", "annotate", "simulate", "render", "diagnose"]


def common_options() -> argparse.ArgumentParser:
    """Options every subcommand takes."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--quiet", "-q", action="store_true", help="no progress bars or stage lines")
    return parent


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pixie",
        description="Physics for 3D Gaussian splats: predict materials, simulate, diagnose.",
        epilog="Run `pixie COMMAND --help` for each command. Exit codes: 0 ok, 1 bad input, "
        "2 usage, 3 computation failed.",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"pixie-gs {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    parents = [common_options()]
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"pixie_gs.cli.cmd_{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"pixie_gs.cli.cmd_{name}":
                continue  # command not built yet
            raise
        module.add_parser(sub, parents)
    return parser


@contextlib.contextmanager
def quiet_float_warnings() -> Iterator[None]:
    """numpy's floating-point warnings ("invalid value encountered in …", "overflow in cast") off for a command:
    every result is checked for NaN and inf and refused in one line, so on bad input these warnings only add
    lines around that error (stop 54's fuzzing found them from meshes, .splat and compressed PLY readers)."""
    import numpy as np

    with np.errstate(all="ignore"):
        yield


def main(argv: list[str] | None = None) -> int:
    thread_defaults()  # before any command imports numpy or torch
    if argv is None:  # the `pixie` process itself, not a caller's: see skip_final_collection
        atexit.register(skip_final_collection)
    try:
        from ..prepare.updir import fix_negative_up

        parser = build_parser()  # imports every command module: Ctrl-C may land here
        args = parser.parse_args(fix_negative_up(list(sys.argv[1:] if argv is None else argv)))
    except KeyboardInterrupt:
        print("pixie: interrupted", file=sys.stderr)
        return exit_interrupted(130, argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    set_quiet(getattr(args, "quiet", False))
    previous = interrupts.install()
    interrupted_code = None
    try:
        with quiet_float_warnings():
            result = args.func(args)
        interrupts.raise_if_interrupted()  # one swallowed after the command's last check still ends it
    except PixieError as exc:
        print(f"pixie {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except interrupts.Terminated:
        interrupts.stop_raising()  # a second signal must not cut the report or the clean-up
        print(f"pixie {args.command}: terminated (SIGTERM); partial output removed", file=sys.stderr)
        interrupted_code = 128 + signal.SIGTERM
    except KeyboardInterrupt:
        interrupts.stop_raising()
        print(f"pixie {args.command}: interrupted", file=sys.stderr)
        interrupted_code = 130
    except MemoryError:
        print(f"pixie {args.command}: error: out of memory (the input or the requested sizes are too large "
              "for this machine)", file=sys.stderr)
        return 3
    except BrokenPipeError:  # stdout closed early (e.g. `pixie info … | head`): stop quietly, like other tools
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:  # permissions, a full disk, an unwritable folder…: one line naming the path
        print(f"pixie {args.command}: error: {os_error_text(exc)}", file=sys.stderr)
        return 1
    finally:
        from ..atomic import remove_live_staging

        interrupts.stop_raising()
        remove_live_staging()  # a signal between two statements must not orphan a staging folder
        if argv is not None:  # a caller that goes on; the `pixie` process itself keeps them through its exit
            interrupts.restore(previous)
    if interrupted_code is not None:  # after the clean-up above
        return exit_interrupted(interrupted_code, argv)
    if argv is None and getattr(args, "exit_at_once", False):
        exit_at_once(int(result or 0))
    return int(result or 0)


def exit_interrupted(code: int, argv: list[str] | None) -> int:
    """`code` for an interrupted command; the `pixie` process itself ends here with it (`exit_at_once`).

    Why: CPython 3.11 marks a KeyboardInterrupt raised inside code run by `exec` of a string (dataclass
    and namedtuple creation while torch imports, where a Ctrl-C often lands) as unhandled even when it is
    caught, and the normal exit of a `python -m pixie_gs` process then kills it with SIGINT: exit status
    -2 instead of 130 (3 of 70 Ctrl-Cs during annotate's start under load; strace showed `kill(self,
    SIGINT)` from Py_RunMain). `os._exit` skips that check."""
    if argv is None:
        exit_at_once(code)
    return code


def exit_at_once(code: int) -> None:
    """End the `pixie` process without the interpreter's teardown, once a command has written and
    closed everything (it sets `args.exit_at_once`; single-file annotate does): atexit callbacks run,
    standard streams flushed, then `os._exit`. Tearing down torch's modules and C++ statics
    took 0.1–0.15 s of a ~2 s annotate. Returns (normal exit) while other Python threads run."""
    import os
    import threading

    if threading.active_count() > 1:
        return
    atexit._run_exitfuncs()  # then the streams, in the interpreter's own order
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # e.g. stdout closed by the reader: what Python's own exit reports
            code = code or 120
    os._exit(code)


def skip_final_collection() -> None:
    """At the exit of a `pixie` process: move every object to gc's permanent generation, so the
    interpreter's last collections do not walk them (torch alone holds several hundred thousand:
    0.5 s of the exit of an annotate at load average 4.5, 0.16 s with this). Streams are still
    flushed and atexit callbacks run; only cyclic garbage left at exit is not collected."""
    gc.freeze()


def os_error_text(exc: OSError) -> str:
    """'PATH: reason' for an OSError (both paths of a failed rename/copy)."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    return f"{' -> '.join(paths)}: {reason}" if paths else reason


if __name__ == "__main__":
    sys.exit(main())
