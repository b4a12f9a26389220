"""Keep a subset of a generated split, in place: by shape key, by class, or the first N objects.

usage: python3 scripts/filter_split.py PART_DIR SPLIT [SHAPE_KEY] [--drop-classes A,B] [--first N]
Why: some shapes are a small share of their recipe's draws (broad-leaved house plants are about 15 % of the
trees), and a training tier that leans on them draws many of the recipe's objects and keeps those; small
experiments (docs/training.md, "Stop 47") train on the first N of them, or on a mix without some classes.
The filters apply in that order: objects whose `shape` lacks SHAPE_KEY (or holds 0 / false) go, then those of
the dropped classes, then all but the first N left. The others lose their .ply and .json; the index is
rewritten with the kept ones, their class counts and `kept_shape_key`, in the order they were drawn.
Exits 1 if none is kept.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def filter_split(part_dir: Path, split: str, shape_key: str | None = None, drop_classes: tuple[str, ...] = (),
                 first: int | None = None) -> tuple[int, int]:
    """Filter PART_DIR/SPLIT in place; returns (kept, drawn)."""
    folder = part_dir / split
    index_path = folder / "index.json"
    index = json.loads(index_path.read_text())
    kept = []
    for entry in index["objects"]:
        stem = Path(entry["file"]).stem
        if shape_key is not None:
            record = json.loads((folder / f"{stem}.json").read_text())
            if not record.get("shape", {}).get(shape_key):
                continue
        if entry["class"] not in drop_classes:
            kept.append(entry)
    if first is not None:
        kept = kept[:first]
    kept_files = {e["file"] for e in kept}
    for entry in index["objects"]:
        if entry["file"] not in kept_files:
            stem = Path(entry["file"]).stem
            (folder / f"{stem}.ply").unlink()
            (folder / f"{stem}.json").unlink()
    classes = sorted({e["class"] for e in kept})
    if shape_key is not None:
        index["kept_shape_key"] = shape_key
    index.update(count=len(kept), classes=classes, drawn=index.get("drawn", len(index["objects"])),
                 class_counts={c: sum(e["class"] == c for e in kept) for c in classes}, objects=kept)
    index_path.write_text(json.dumps(index, indent=1))
    return len(kept), index["drawn"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("part_dir", type=Path)
    ap.add_argument("split")
    ap.add_argument("shape_key", nargs="?", default=None, help="keep objects whose shape has this key")
    ap.add_argument("--drop-classes", default="", metavar="A,B", help="comma-separated classes to drop")
    ap.add_argument("--first", type=int, default=None, metavar="N", help="keep only the first N objects left")
    args = ap.parse_args()
    if args.first is not None and args.first < 1:
        ap.error(f"--first must be ≥ 1 (got {args.first})")
    drop = tuple(c for c in args.drop_classes.split(",") if c)
    kept, drawn = filter_split(args.part_dir, args.split, args.shape_key, drop, args.first)
    print(f"kept {kept} of {drawn} objects in {args.part_dir}/{args.split}")
    return 0 if kept else 1


if __name__ == "__main__":
    raise SystemExit(main())
