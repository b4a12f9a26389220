"""Write outputs all-or-nothing: to a temporary file in the target directory, then rename."""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

from .errors import InputError
from .interrupts import deferred, raise_if_interrupted


@contextlib.contextmanager
def atomic_path(target: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to `target`; on success rename it onto `target`.

    On any exception the temporary file is removed and `target` is left untouched, so a
    failed run never leaves a partial or clobbered output behind.
    """
    target = Path(target)
    directory = target.parent if str(target.parent) else Path(".")
    if not directory.is_dir():
        raise InputError("output directory does not exist", directory)
    remove_stale_temp_files(target)
    fd, tmp_name = tempfile.mkstemp(
        prefix=_temp_prefix(target, os.getpid()), suffix=suffix if suffix is not None else ".tmp", dir=directory
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if tmp.exists():  # mkstemp creates 0600; give the output the user's usual permissions
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        raise_if_interrupted()  # a Ctrl-C/SIGTERM swallowed in a finalizer must not let the output through
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


TEMP_TAG = ".pixie-tmp-"


def _temp_prefix(target: Path, pid: int) -> str:
    """Name prefix of the temporary files that process `pid` writes for `target` (the PID lets a
    later run tell a file of a killed run from one still being written)."""
    return f".{target.name}{TEMP_TAG}{pid}-"


def remove_stale_temp_files(target: str | Path) -> int:
    """Delete temporary files of `target` left by runs that were killed (SIGKILL cannot be
    handled, so the next write to the same target cleans up). Returns how many were removed."""
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    prefix = f".{target.name}{TEMP_TAG}"
    removed = 0
    with contextlib.suppress(OSError):
        for entry in parent.iterdir():
            if not entry.name.startswith(prefix):
                continue
            pid_text = entry.name[len(prefix):].split("-", 1)[0]
            if not pid_text.isdigit() or int(pid_text) == os.getpid() or _pid_alive(int(pid_text)):
                continue
            with contextlib.suppress(OSError):
                entry.unlink()
                removed += 1
    return removed


def check_distinct_output(inp: str | Path, out: str | Path, force: bool = False) -> None:
    """Refuse to write OUT over IN (the input is never modified) unless `force` is set."""
    inp, out = Path(inp), Path(out)
    if out.exists() and inp.exists() and os.path.samefile(inp, out) and not force:
        raise InputError("output is the input file; refusing to overwrite it (use --force)", out)


# ---------------------------------------------------------------------------------- staged folders
STAGING_TAG = ".pixie-staging-"
_LIVE_STAGING: set[Path] = set()  # staging folders of this process not yet committed or aborted


def exchange_paths(a: Path, b: Path) -> bool:
    """Swap two directory entries of one file system atomically (Linux renameat2 RENAME_EXCHANGE).

    Returns False when the platform or file system cannot, so the caller falls back to two renames.
    """
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (22, 38, 95):  # EINVAL, ENOSYS, EOPNOTSUPP: not supported here
        return False
    raise OSError(err, os.strerror(err), str(a), None, str(b))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_staging(target: Path) -> None:
    """Delete staging folders of `target` left by runs that were killed (their process is gone)."""
    import shutil

    parent = target.parent
    if not parent.is_dir():
        return
    prefix = f".{target.name}{STAGING_TAG}"
    for entry in parent.iterdir():
        if not entry.name.startswith(prefix):
            continue
        try:
            pid = int(entry.name[len(prefix):].split("-", 1)[0])
        except ValueError:
            continue
        if pid != os.getpid() and not _pid_alive(pid):
            if entry.name.endswith("-old") and not target.exists():
                os.rename(entry, target)  # killed between the two renames of a fallback swap: put it back
            else:
                shutil.rmtree(entry, ignore_errors=True)


class StagedDirectory:
    """Build a folder's new content beside it, then swap it in whole.

    `path` is a fresh hidden folder next to `target` (same file system). `commit()` puts it at
    `target`: a plain rename when `target` does not exist, otherwise an atomic exchange (two
    renames where the OS cannot), after hard-linking into it the entries of the old folder that
    `keep(name)` selects (so they survive); the old content is then deleted. `abort()` (or any
    exception/signal inside `with`) deletes the staging folder and leaves `target` untouched.
    """

    def __init__(self, target: str | Path) -> None:
        self.target = Path(os.path.realpath(target))  # through symlinks: the real folder is what gets swapped
        if not self.target.parent.is_dir():
            raise InputError("parent directory does not exist", self.target.parent)
        remove_stale_staging(self.target)
        with deferred():  # a Ctrl-C/SIGTERM between mkdir and registration would orphan the folder
            self.path = Path(tempfile.mkdtemp(prefix=f".{self.target.name}{STAGING_TAG}{os.getpid()}-",
                                              dir=self.target.parent))
            _LIVE_STAGING.add(self.path)
        try:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self.path, 0o777 & ~umask)
        except BaseException:
            self.abort()
            raise

    def commit(self, keep=lambda name: False) -> Path:
        import shutil

        raise_if_interrupted()  # a Ctrl-C/SIGTERM swallowed in a finalizer must not let the new content in
        if not self.target.exists():
            os.rename(self.path, self.target)
            return self.target
        for entry in self.target.iterdir():
            if keep(entry.name):
                os.link(entry, self.path / entry.name, follow_symlinks=False)
        with deferred():  # the swap and the bookkeeping of what self.path now holds go together
            if not exchange_paths(self.path, self.target):
                old = self.path.with_name(self.path.name + "-old")
                os.rename(self.target, old)
                os.rename(self.path, self.target)
                _LIVE_STAGING.discard(self.path)
                self.path = old
                _LIVE_STAGING.add(old)
        shutil.rmtree(self.path, ignore_errors=True)  # now the previous content
        _LIVE_STAGING.discard(self.path)
        return self.target

    def abort(self) -> None:
        import shutil

        shutil.rmtree(self.path, ignore_errors=True)
        _LIVE_STAGING.discard(self.path)


def remove_live_staging() -> None:
    """Delete every staging folder of this process that was neither committed nor aborted (called by
    the CLI when a command ends, so even a signal between two statements leaves nothing behind)."""
    import shutil

    for path in list(_LIVE_STAGING):
        shutil.rmtree(path, ignore_errors=True)
        _LIVE_STAGING.discard(path)
