"""Read a generated dataset for training: the objects of a split and one object with its labels."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError, read_json_file
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
    index = read_json_file(index_path, "a dataset index")
    objects = index.get("objects") if isinstance(index, dict) else None
    if not isinstance(objects, list):
        raise InputError("malformed dataset index (needs an 'objects' list)", index_path)
    folder = index_path.parent.resolve()
    paths = []
    for i, entry in enumerate(objects):
        name = entry.get("file") if isinstance(entry, dict) else None
        if not isinstance(name, str) or not name:
            raise InputError(f"malformed dataset index (objects[{i}] needs a 'file' name)", index_path)
        paths.append(confined_path(folder, name, index_path, f"objects[{i}].file"))
    return paths


def confined_path(folder: Path, name: str, source: Path, key: str) -> Path:
    """`folder / name` when `name` is a relative path that stays inside `folder` (symlinks
    resolved); InputError otherwise, so an index never reaches files outside its dataset."""
    rel = Path(name)
    if rel.is_absolute() or ".." in rel.parts or "\x00" in name:
        raise InputError(f"{key} {name[:80]!r} must be a path inside the dataset folder", source)
    path = folder / rel
    if folder not in path.resolve().parents:
        raise InputError(f"{key} {name[:80]!r} leads outside the dataset folder", source)
    return path


def load_object(path: str | Path) -> tuple[SplatCloud, dict]:
    """One labelled object: the splat (with material_id, E, nu, density, part_id) and its record."""
    path = Path(path)
    meta_path = path.with_suffix(".json")
    if not meta_path.exists():
        raise InputError(f"has no label record ({meta_path.name} missing)", path)
    cloud = read_splat(path)
    meta = read_json_file(meta_path, "a label record")
    if not isinstance(meta, dict):
        raise InputError("malformed label record (must be a JSON object)", meta_path)
    if not cloud.has_materials() or not cloud.has("part_id"):
        raise InputError("has no material labels (material_id, E, nu, density, part_id)", path)
    return cloud, meta
