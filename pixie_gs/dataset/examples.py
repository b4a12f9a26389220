"""Build the example splats shipped in pixie_gs/data/examples/ (demo and docs inputs).

    python -m pixie_gs.dataset.examples [OUT_DIR]

Each example is a generated object (test-split seeds, so never a training object) with its
material attributes (material_id, E, nu, density, part_id) removed, so that `pixie annotate`
has the work to do; the object's label record is written beside it as NAME.labels.json
(ground truth for comparisons). Deterministic: the same files every time.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Callable

from ..atomic import atomic_path
from ..splat import LABEL_ATTRIBUTES, SplatCloud
from .assemble import build_object
from .generate import object_seed
from .labels import load_class_table

EXAMPLES_DIR = Path(__file__).resolve().parent.parent / "data" / "examples"
EXAMPLE_SEED = 2026
SEARCH_LIMIT = 200

# name: (class, Gaussians requested, what the example must show)
EXAMPLES: dict[str, tuple[str, int, Callable[[dict], bool]]] = {
    "tree": ("tree", 24_000, lambda r: r["shape"]["pot"] and r["shape"]["kind"] == "broadleaf"),
    "duck": ("rubber_ducks_toys", 12_000,
             lambda r: r["shape"]["kind"] == "duck" and r["shape"]["body_rgb"][2] < 0.4 < r["shape"]["body_rgb"][1]),
    "can": ("soda_cans", 10_000, lambda r: not r["shape"]["lying"]),
    "sand": ("sand", 12_000, lambda r: True),
    "snow": ("snow_mud", 12_000, lambda r: True),
}


def strip_labels(cloud: SplatCloud) -> SplatCloud:
    """A copy without the label attributes (material_id, E, nu, density, part_id)."""
    out = cloud.copy()
    for name in LABEL_ATTRIBUTES:
        out.extras.pop(name, None)
    out.property_order = [p for p in out.property_order if p not in LABEL_ATTRIBUTES]
    return out


def build_example(name: str) -> tuple[SplatCloud, dict]:
    """The first test-split object of the example's class that shows what the example needs."""
    class_name, n_gaussians, wanted = EXAMPLES[name]
    spec = load_class_table()[class_name]
    for i in range(SEARCH_LIMIT):
        seed = object_seed(EXAMPLE_SEED, "test", i)
        _, probe = build_object(spec, seed, 200)  # shapes do not depend on the Gaussian count
        if wanted(probe):
            cloud, record = build_object(spec, seed, n_gaussians)
            return cloud, record
    raise RuntimeError(f"no suitable {class_name} among {SEARCH_LIMIT} seeds")


def write_examples(out_dir: Path = EXAMPLES_DIR) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name in EXAMPLES:
        cloud, record = build_example(name)
        strip_labels(cloud).write(out_dir / f"{name}.ply")
        with atomic_path(out_dir / f"{name}.labels.json") as tmp:
            tmp.write_text(json.dumps(record, indent=1) + "\n")
        written.append(out_dir / f"{name}.ply")
    return written


if __name__ == "__main__":
    from ..progress import set_quiet

    set_quiet(True)
    for path in write_examples(Path(sys.argv[1]) if len(sys.argv) > 1 else EXAMPLES_DIR):
        print(f"{path}  {path.stat().st_size / 1e6:.2f} MB")
