"""Merge several generated copies of one split (e.g. made with different --gaussians) into one split.

usage: python3 scripts/merge_splits.py OUT_DIR SPLIT PART_DIR [PART_DIR ...]
Each PART_DIR holds PART_DIR/SPLIT/index.json from `pixie generate`. Files are moved (renamed with the
part's position as prefix so names never clash) into OUT_DIR/SPLIT, and the merged index lists the
objects interleaved round-robin over the parts, so any prefix (`--limit-train K`) mixes every part.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path


def merge(out_dir: Path, split: str, parts: list[Path]) -> int:
    target = out_dir / split
    target.mkdir(parents=True, exist_ok=False)
    lists = []
    for k, part in enumerate(parts):
        index = json.loads((part / split / "index.json").read_text())
        entries = []
        for e in index["objects"]:
            stem = Path(e["file"]).stem
            new = f"p{k}_{stem}"
            (part / split / f"{stem}.ply").rename(target / f"{new}.ply")
            record = json.loads((part / split / f"{stem}.json").read_text())
            record["file"] = f"{new}.ply"
            (target / f"{new}.json").write_text(json.dumps(record))
            # a merged part already names each object's count; a generated one names its own
            requested = e.get("gaussians_requested", index.get("gaussians_requested"))
            entries.append({**e, "file": f"{new}.ply", "part": k, "gaussians_requested": requested})
        lists.append(entries)
    merged = [lst[i] for i in range(max(map(len, lists))) for lst in lists if i < len(lst)]
    classes = sorted({e["class"] for e in merged})
    (target / "index.json").write_text(json.dumps({
        "format_version": 1, "split": split, "count": len(merged), "classes": classes,
        "class_counts": {c: sum(e["class"] == c for e in merged) for c in classes},
        "merged_from": [str(p) for p in parts], "objects": merged}, indent=1))
    return len(merged)


if __name__ == "__main__":
    if len(sys.argv) < 4 or sys.argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        sys.exit(0 if len(sys.argv) > 1 and sys.argv[1] in ("-h", "--help") else 2)
    n = merge(Path(sys.argv[1]), sys.argv[2], [Path(p) for p in sys.argv[3:]])
    print(f"merged {n} objects into {sys.argv[1]}/{sys.argv[2]}")
