"""Keep only the objects of a generated split whose shape parameters carry a key (e.g. `broad_leaves`).

usage: python3 scripts/filter_split.py PART_DIR SPLIT SHAPE_KEY
Why: some shapes are a small share of their recipe's draws (broad-leaved house plants are about 15 % of the
trees), and a training tier that leans on them draws many of the recipe's objects and keeps those. The objects
whose `shape` lacks SHAPE_KEY (or holds 0 / false) lose their .ply and .json; the index is rewritten with the
kept ones, their class counts and `kept_shape_key`, in the order they were drawn. Exits 1 if none is kept.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path


def filter_split(part_dir: Path, split: str, shape_key: str) -> tuple[int, int]:
    """Filter PART_DIR/SPLIT in place; returns (kept, drawn)."""
    folder = part_dir / split
    index_path = folder / "index.json"
    index = json.loads(index_path.read_text())
    kept = []
    for entry in index["objects"]:
        stem = Path(entry["file"]).stem
        record = json.loads((folder / f"{stem}.json").read_text())
        if record.get("shape", {}).get(shape_key):
            kept.append(entry)
        else:
            (folder / f"{stem}.ply").unlink()
            (folder / f"{stem}.json").unlink()
    classes = sorted({e["class"] for e in kept})
    index.update(count=len(kept), classes=classes, kept_shape_key=shape_key, drawn=len(index["objects"]),
                 class_counts={c: sum(e["class"] == c for e in kept) for c in classes}, objects=kept)
    index_path.write_text(json.dumps(index, indent=1))
    return len(kept), index["drawn"]


if __name__ == "__main__":
    if len(sys.argv) != 4 or sys.argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        sys.exit(0 if len(sys.argv) > 1 and sys.argv[1] in ("-h", "--help") else 2)
    kept, drawn = filter_split(Path(sys.argv[1]), sys.argv[2], sys.argv[3])
    print(f"kept {kept} of {drawn} objects in {sys.argv[1]}/{sys.argv[2]} whose shape has '{sys.argv[3]}'")
    sys.exit(0 if kept else 1)
