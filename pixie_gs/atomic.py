"""Write outputs all-or-nothing: to a temporary file in the target directory, then rename."""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

from .errors import InputError


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
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{target.name}.", suffix=suffix if suffix is not None else ".tmp", dir=directory
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if tmp.exists():  # mkstemp creates 0600; give the output the user's usual permissions
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def check_distinct_output(inp: str | Path, out: str | Path, force: bool = False) -> None:
    """Refuse to write OUT over IN (the input is never modified) unless `force` is set."""
    inp, out = Path(inp), Path(out)
    if out.exists() and inp.exists() and os.path.samefile(inp, out) and not force:
        raise InputError("output is the input file; refusing to overwrite it (use --force)", out)
