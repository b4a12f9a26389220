"""Which files a batch annotates: inputs from a folder, a glob or a manifest; their output names;
`--shard i/N` (or the SLURM array variables); resume (finished outputs are skipped)."""
from __future__ import annotations

import glob
import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

# Suffixes of the splat files a folder listing picks up (`.compressed.ply` ends in `.ply`).
SPLAT_SUFFIXES = (".ply", ".splat", ".spz")
MANIFEST_SUFFIXES = (".txt", ".lst", ".list", ".manifest")
GLOB_CHARS = set("*?[")


@dataclass(frozen=True)
class Job:
    """One asset: `index` in the sorted list of all inputs (before sharding), input and output paths."""

    index: int
    input: str
    output: str


def is_batch_input(spec: str) -> bool:
    """True when IN names many files: a folder, a glob pattern or a manifest (a .txt/.lst list)."""
    p = Path(spec)
    if p.is_dir():
        return True
    if not p.exists() and GLOB_CHARS & set(spec):
        return True
    return p.suffix.lower() in MANIFEST_SUFFIXES


def list_inputs(spec: str) -> list[Path]:
    """The input files of a batch, sorted by path: the splat files directly inside a folder, the files
    a glob matches (`**` recurses; quote it), or the lines of a manifest (one path per line, relative
    to the manifest's folder; blank lines and `#` comments ignored). InputError when there are none."""
    p = Path(spec)
    if p.is_dir():
        files = [f for f in p.iterdir() if f.is_file() and f.name.lower().endswith(SPLAT_SUFFIXES)
                 and not f.name.startswith(".")]
        if not files:
            raise InputError(f"folder holds no splat file ({', '.join(SPLAT_SUFFIXES)})", p)
    elif p.suffix.lower() in MANIFEST_SUFFIXES and p.exists():
        files = _read_manifest(p)
    elif GLOB_CHARS & set(spec):
        files = [Path(f) for f in glob.glob(spec, recursive=True) if Path(f).is_file()]
        if not files:
            raise InputError("pattern matches no file", spec)
    else:
        raise InputError("no such folder, manifest or file pattern", spec)
    return sorted(files, key=lambda f: str(f))


def _read_manifest(path: Path) -> list[Path]:
    from ..errors import require_file

    require_file(path, "a manifest")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError:
        raise InputError("manifest is not UTF-8 text (one splat path per line)", path) from None
    files = []
    for line in lines:
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        f = Path(line).expanduser()
        files.append(f if f.is_absolute() else path.parent / f)
    if not files:
        raise InputError("manifest lists no file", path)
    return files


def output_name(path: Path) -> str:
    """`NAME.ply` for an input `NAME.ply`, `NAME.splat`, `NAME.spz` or `NAME.compressed.ply`
    (the annotated splat is always an INRIA .ply: that is the format that carries the materials)."""
    name = path.name
    for suffix in (".compressed.ply",) + SPLAT_SUFFIXES:
        if name.lower().endswith(suffix):
            return name[: -len(suffix)] + ".ply"
    return path.stem + ".ply"


def make_jobs(inputs: list[Path], out_dir: str | Path) -> list[Job]:
    """One Job per input, outputs in `out_dir`. InputError when two inputs would write the same
    output, or an output would overwrite its input."""
    out_dir = Path(out_dir)
    seen: dict[str, Path] = {}
    jobs = []
    for i, inp in enumerate(inputs):
        out = out_dir / output_name(inp)
        if out.name in seen:
            raise InputError(f"two inputs would write the same output {out} ({seen[out.name]} and {inp}); "
                             "rename one or list them in separate batches", inp)
        seen[out.name] = inp
        if out.exists() and inp.exists() and os.path.samefile(out, inp):
            raise InputError("the output folder holds the inputs: the outputs would overwrite them; "
                             "choose another output folder", out_dir)
        jobs.append(Job(i, str(inp), str(out)))
    return jobs


def parse_shard(text: str | None, env: dict | None = None) -> tuple[int, int]:
    """(i, N) from `--shard i/N` (0 ≤ i < N); without it, from SLURM_ARRAY_TASK_ID minus
    SLURM_ARRAY_TASK_MIN (0 when unset) and SLURM_ARRAY_TASK_COUNT; else (0, 1): everything."""
    env = os.environ if env is None else env
    if text is None:
        if "SLURM_ARRAY_TASK_ID" not in env or "SLURM_ARRAY_TASK_COUNT" not in env:
            return 0, 1
        try:
            i = int(env["SLURM_ARRAY_TASK_ID"]) - int(env.get("SLURM_ARRAY_TASK_MIN", "0"))
            n = int(env["SLURM_ARRAY_TASK_COUNT"])
        except ValueError:
            raise InputError("SLURM_ARRAY_TASK_ID/COUNT/MIN are not integers; pass --shard i/N") from None
        where = "SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN"
    else:
        try:
            a, b = text.split("/")
            i, n = int(a), int(b)
        except ValueError:
            raise InputError(f"--shard '{text}' is not i/N (e.g. 0/4)") from None
        where = "--shard"
    if n < 1 or not 0 <= i < n:
        raise InputError(f"{where}: shard {i} of {n} does not exist (need 0 ≤ i < N)")
    return i, n


def select_shard(jobs: list[Job], i: int, n: int) -> list[Job]:
    """Every N-th job starting at i (by the index in the sorted input list: the same on every node)."""
    return [j for j in jobs if j.index % n == i]


def is_finished(job: Job, prepared: bool) -> bool:
    """True when the job's output is complete: the .ply exists (written atomically, so it exists only
    whole) and, when preparation is on, its .prepare.json too (written after the .ply)."""
    from ..prepare import sidecar_path

    out = Path(job.output)
    return out.is_file() and (not prepared or sidecar_path(out).is_file())
