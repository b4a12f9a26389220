"""Contact sheet of a generated split: each object by its RGB and by its material labels."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..materials import LOG10_E_RANGE, MATERIAL_COLORS
from ..render import contact_sheet, render_points, save_png
from ..splat import SplatCloud
from .loader import list_objects, load_object


def material_colours(cloud: SplatCloud) -> np.ndarray:
    """Per-Gaussian display colour: the material's colour, brighter for stiffer parts (log10 E)."""
    material_id, E, _nu, _rho = cloud.get_materials()
    base = MATERIAL_COLORS[np.clip(material_id, 0, len(MATERIAL_COLORS) - 1)]
    lo, hi = LOG10_E_RANGE
    stiffness = np.clip((np.log10(np.maximum(E, 1e-30)) - lo) / (hi - lo), 0.0, 1.0)
    return np.clip(base * (0.45 + 0.75 * stiffness[:, None]), 0.0, 1.0)


def pick_examples(paths: list[Path], per_class: int) -> list[Path]:
    """Up to `per_class` objects of each class, in the order the classes first appear."""
    chosen: dict[str, list[Path]] = {}
    for p in paths:
        cls = p.stem.split("_", 1)[1] if "_" in p.stem else p.stem
        bucket = chosen.setdefault(cls, [])
        if len(bucket) < per_class:
            bucket.append(p)
    return [p for bucket in chosen.values() for p in bucket]


def write_preview(data_dir: str | Path, split: str, png: str | Path, per_class: int = 2,
                  cell_px: int = 200) -> int:
    """Render up to `per_class` objects per class (RGB view and material view side by side) into
    one PNG; returns the number of objects shown."""
    images, labels = [], []
    examples = pick_examples(list_objects(data_dir, split), per_class)
    for path in examples:
        cloud, meta = load_object(path)
        lo, hi = cloud.bounds()
        for colours, what in ((cloud.rgb(), "rgb"), (material_colours(cloud), "material")):
            images.append(render_points(cloud.means, colours, size=(cell_px, cell_px), azimuth_deg=-60.0,
                                        elevation_deg=15.0, bounds=(lo, hi)))
            labels.append(f"{meta['class']} {what}")
    save_png(contact_sheet(images, labels, columns=4), png)
    return len(examples)
