"""Read a generated dataset for training: the objects of a split and one object with its labels."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError
from ..splat import SplatCloud, read_splat
from .generate import INDEX_NAME, SPLITS


def list_objects(data_dir: str | Path, split: str) -> list[Path]:
    """Paths of the .ply files of `split` under `data_dir`, in index order (from its index.json)."""
    if split not in SPLITS:
        raise InputError(f"unknown split '{split}' (choose from {', '.join(SPLITS)})")
    index_path = Path(data_dir) / split / INDEX_NAME
    if not index_path.exists():
        raise InputError(f"no '{split}' split here (missing {split}/{INDEX_NAME}; run `pixie generate`)",
                         data_dir)
    try:
        index = json.loads(index_path.read_text())
        files = [entry["file"] for entry in index["objects"]]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise InputError(f"malformed dataset index ({type(exc).__name__}: {exc})", index_path) from None
    return [index_path.parent / name for name in files]


def load_object(path: str | Path) -> tuple[SplatCloud, dict]:
    """One labelled object: the splat (with material_id, E, nu, density, part_id) and its record."""
    path = Path(path)
    meta_path = path.with_suffix(".json")
    if not meta_path.exists():
        raise InputError(f"has no label record ({meta_path.name} missing)", path)
    cloud = read_splat(path)
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"malformed label record ({exc.msg} at line {exc.lineno})", meta_path) from None
    if not cloud.has_materials() or not cloud.has("part_id"):
        raise InputError("has no material labels (material_id, E, nu, density, part_id)", path)
    return cloud, meta
