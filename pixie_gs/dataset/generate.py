"""Generate a split of labelled objects: seeds, balanced class order, parallel workers, index.

Layout: OUT_DIR/<split>/<index:06d>_<class>.ply with a sidecar .json (the object's index record)
and OUT_DIR/<split>/index.json listing every object. A split is written into a hidden temporary
directory and renamed into place when complete, so a failed run leaves no partial split.
Object i's seed depends only on (seed, split, i): the bytes do not depend on the worker count.
With `pair_share` > 0, that share of the objects are pairs (dataset/pairs.py): the object and a partner
of another category side by side, named OUT_DIR/<split>/<index:06d>_<class>+<partner>.ply. With
`floor_share` > 0, that share stand on a floor disc labelled stationary (dataset/floor.py).
"""
from __future__ import annotations

import contextlib
import json
import multiprocessing
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import StagedDirectory
from ..errors import InputError
from ..progress import is_quiet, progress, set_quiet
from .assemble import build_object, extent_record
from .labels import ClassSpec, load_class_table
from .leftovers import LEFTOVER_OBJECT_SHARE
from .lighting import LIGHTING_OBJECT_SHARE
from .floor import floor_record, with_floor
from .pairs import MIN_PAIR_GAUSSIANS, build_pair

SPLITS = ("train", "val", "test")
# Mixed into every object seed so that the splits never share a seed (see object_seed).
SPLIT_SALT = {"train": 0x7261696E, "val": 0x76616C00, "test": 0x74657374}
PAIR_SALT = 0x70616972  # the stream that decides which objects are pairs and with whom
FLOOR_SALT = 0x666C6F72  # the stream that decides which objects stand on a floor, and draws the floor
INDEX_NAME = "index.json"
FORMAT_VERSION = 1


def object_seed(seed: int, split: str, index: int) -> int:
    """64-bit seed of object `index` of `split` (SeedSequence of (seed, split salt, index))."""
    if split not in SPLIT_SALT:
        raise InputError(f"unknown split '{split}' (choose from {', '.join(SPLITS)})")
    state = np.random.SeedSequence([int(seed), SPLIT_SALT[split], int(index)]).generate_state(2, np.uint32)
    return int(state[0]) << 32 | int(state[1])


def object_side_stream(seed: int, split: str, index: int, salt: int) -> np.random.Generator:
    """A random stream of object `index` apart from its seed's (seed, split, index, `salt`): what it draws
    leaves the object's own draws, and so the files of objects it does not touch, unchanged."""
    return np.random.default_rng([int(seed), SPLIT_SALT[split], int(index), salt])


def partner_for_index(seed: int, split: str, index: int, classes: list[str], pair_share: float) -> str | None:
    """The partner category of object `index` (another of `classes`), or None when it stands alone.

    Drawn from its own stream (seed, split, index, PAIR_SALT), so objects that stand alone are the same
    files with or without pairs elsewhere in the split, and a pair's partner does not depend on workers."""
    if pair_share <= 0 or len(classes) < 2:
        return None
    rng = object_side_stream(seed, split, index, PAIR_SALT)
    if rng.random() >= pair_share:
        return None
    own = class_for_index(index, classes)
    others = [c for c in classes if c != own]
    return others[int(rng.integers(len(others)))]


def floor_seed_for_index(seed: int, split: str, index: int, floor_share: float) -> int | None:
    """The seed of object `index`'s floor (dataset/floor.py), or None when it stands on none; from its own
    stream (seed, split, index, FLOOR_SALT), so objects without a floor are the same files either way."""
    if floor_share <= 0:
        return None
    rng = object_side_stream(seed, split, index, FLOOR_SALT)
    if rng.random() >= floor_share:
        return None
    return int(rng.integers(0, 2**63 - 1))


def class_for_index(index: int, classes: list[str]) -> str:
    """Round-robin class order: every class gets ⌊N/k⌋ or ⌈N/k⌉ of N objects."""
    return classes[index % len(classes)]


def object_stem(index: int, class_name: str, partner: str | None = None) -> str:
    return f"{index:06d}_{class_name}" + (f"+{partner}" if partner else "")


@dataclass(frozen=True)
class ObjectTask:
    """Everything a worker needs to build and write one object (picklable, spawn-safe)."""

    index: int
    class_name: str
    seed: int
    n_gaussians: int
    directory: str
    table_path: str | None
    realistic: bool = True
    partner: str | None = None  # the partner's category: this object is a pair (dataset/pairs.py)
    floor_seed: int | None = None  # the object stands on a floor drawn from this seed (dataset/floor.py)
    leftover_share: float = LEFTOVER_OBJECT_SHARE  # chance of interior leftovers (dataset/leftovers.py)
    lighting_share: float = LIGHTING_OBJECT_SHARE  # chance of baked lighting (dataset/lighting.py)


_TABLE_CACHE: dict[str | None, dict[str, ClassSpec]] = {}


def _table(path: str | None) -> dict[str, ClassSpec]:
    if path not in _TABLE_CACHE:
        _TABLE_CACHE[path] = load_class_table(path)
    return _TABLE_CACHE[path]


def write_object(task: ObjectTask) -> dict:
    """Build object `task.index` and write its .ply and .json; returns its index entry."""
    spec = _table(task.table_path)[task.class_name]
    was_quiet = is_quiet()
    set_quiet(True)  # per-piece bars (e.g. the converter's interior fill) would bury the object bar
    try:
        if task.partner is None:
            cloud, record = build_object(spec, task.seed, task.n_gaussians, task.realistic, task.leftover_share,
                                         task.lighting_share)
        else:
            partner = _table(task.table_path)[task.partner]
            cloud, record = build_pair(spec, partner, task.seed, task.n_gaussians, task.realistic,
                                       task.leftover_share, task.lighting_share)
        if task.floor_seed is not None:
            cloud, n_floor = with_floor(cloud, np.random.default_rng(task.floor_seed))
            record = {**record, **extent_record(cloud), "floor": floor_record(n_floor)}
    finally:
        set_quiet(was_quiet)
    stem = object_stem(task.index, task.class_name, task.partner)
    directory = Path(task.directory)
    record = {"index": task.index, "file": f"{stem}.ply", **record}
    cloud.write(directory / f"{stem}.ply")
    (directory / f"{stem}.json").write_text(json.dumps(record, indent=1) + "\n")
    entry = {"index": task.index, "class": task.class_name, "file": record["file"], "seed": task.seed,
             "gaussians": record["gaussians"], "parts": [p["name"] for p in record["parts"]]}
    if task.partner is not None:
        entry["partner"] = task.partner
    if task.floor_seed is not None:
        entry["floor"] = record["floor"]["count"]
    return entry


def resolve_classes(table: dict[str, ClassSpec], names: list[str] | None) -> list[str]:
    """The requested class names in table order (all when `names` is empty); InputError for unknowns."""
    if not names:
        return list(table)
    unknown = [n for n in names if n not in table]
    if unknown:
        raise InputError(f"unknown class(es) {', '.join(unknown)} (choose from {', '.join(table)})")
    return [n for n in table if n in set(names)]


def generate_split(out_dir: str | Path, count: int, *, classes: list[str] | None = None, seed: int = 0,
                   split: str = "train", workers: int = 1, n_gaussians: int = 50_000,
                   table_path: str | Path | None = None, force: bool = False, realistic: bool = True,
                   pair_share: float = 0.0, floor_share: float = 0.0,
                   leftover_share: float = LEFTOVER_OBJECT_SHARE,
                   lighting_share: float = LIGHTING_OBJECT_SHARE) -> Path:
    """Write `count` objects of `split` under `out_dir`; returns the split directory.

    Classes are assigned round-robin; objects are built in `workers` spawned processes (1: in this
    process). Refuses to replace an existing split unless `force`. `realistic`: objects look like trained
    captures (pixie_gs/dataset/realism.py); False gives the clean converter output. `pair_share`: the
    share of objects stood beside a partner of another category (dataset/pairs.py; needs ≥ 2 classes).
    `floor_share`: the share stood on a floor disc labelled stationary (dataset/floor.py).
    `leftover_share`: the share of realistic objects holding interior leftovers (dataset/leftovers.py).
    `lighting_share`: the share of realistic objects whose colours carry baked lighting (dataset/lighting.py).
    """
    if count < 1:
        raise InputError(f"--count must be ≥ 1 (got {count})")
    if n_gaussians < 100:
        raise InputError(f"--gaussians must be ≥ 100 (got {n_gaussians})")
    if workers < 1:
        raise InputError(f"--workers must be ≥ 1 (got {workers})")
    if not 0.0 <= pair_share <= 1.0:
        raise InputError(f"--pairs must be a share from 0 to 1 (got {pair_share})")
    if not 0.0 <= floor_share <= 1.0:
        raise InputError(f"--floors must be a share from 0 to 1 (got {floor_share})")
    if not 0.0 <= leftover_share <= 1.0:
        raise InputError(f"--leftovers must be a share from 0 to 1 (got {leftover_share})")
    if not 0.0 <= lighting_share <= 1.0:
        raise InputError(f"--lighting must be a share from 0 to 1 (got {lighting_share})")
    if pair_share > 0 and n_gaussians < MIN_PAIR_GAUSSIANS:
        raise InputError(f"--pairs needs --gaussians ≥ {MIN_PAIR_GAUSSIANS} (half for each object; got {n_gaussians})")
    table_arg = None if table_path is None else str(Path(table_path).resolve())
    table = _table(table_arg)
    chosen = resolve_classes(table, classes)
    if pair_share > 0 and len(chosen) < 2:
        raise InputError(f"--pairs needs at least two classes (got {', '.join(chosen)})")
    object_seed(seed, split, 0)  # validates the split name
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("exists and is not a directory", out_dir)
    created = [d for d in (out_dir, *out_dir.parents) if not d.exists()]  # folders this run makes
    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / split
    if final.exists() and not force:
        raise InputError(f"already holds a '{split}' split (use --force to replace it)", final)
    staging = StagedDirectory(final)  # the split is built beside `final` and swapped in whole
    partial = staging.path
    tasks = [ObjectTask(i, class_for_index(i, chosen), object_seed(seed, split, i), n_gaussians, str(partial),
                        table_arg, realistic, partner_for_index(seed, split, i, chosen, pair_share),
                        floor_seed_for_index(seed, split, i, floor_share), leftover_share, lighting_share)
             for i in range(count)]
    try:
        entries = _run_tasks(tasks, workers)
        index = {"format_version": FORMAT_VERSION, "split": split, "seed": int(seed), "count": count,
                 "gaussians_requested": n_gaussians, "classes": chosen,
                 "class_counts": {c: sum(e["class"] == c for e in entries) for c in chosen},
                 "pair_share": pair_share, "pairs": sum("partner" in e for e in entries),
                 "floor_share": floor_share, "floors": sum("floor" in e for e in entries),
                 "leftover_share": leftover_share if realistic else 0.0,
                 "lighting_share": lighting_share if realistic else 0.0,
                 "objects": entries}
        (partial / INDEX_NAME).write_text(json.dumps(index, indent=1) + "\n")
        staging.commit()
    except BaseException:
        staging.abort()
        for d in created:  # innermost first: leave no empty folder behind
            with contextlib.suppress(OSError):
                d.rmdir()
        raise
    return final


def _run_tasks(tasks: list[ObjectTask], workers: int) -> list[dict]:
    desc = "generate objects"
    if workers == 1 or len(tasks) == 1:
        return [write_object(t) for t in progress(tasks, desc, total=len(tasks), unit="obj")]
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(processes=min(workers, len(tasks))) as pool:
        entries = list(progress(pool.imap(write_object, tasks, chunksize=1), desc, total=len(tasks), unit="obj"))
        pool.close()
        pool.join()
    return entries
