"""The label floor: the part of the normalised MSE that no model can remove on generated data.

`pixie generate` draws every part's E and ρ log-uniformly and ν uniformly within the part's range in the
class table (dataset/labels.py), independently of anything the splat shows. The best any predictor can do
for such a part is the middle of its range, and its squared error is then the variance of the draw: for a
range of width w in the model's normalised units (materials.py maps each label range onto [-1, 1]), w²/12.
Averaged over a split's Gaussians, that is the floor under `pixie evaluate`'s MSE columns; a model's
distance above it is what it can still learn. (Constraints such as `leaves.E < trunk.E` reject a few
draws, so the true floor is slightly lower; for the shipped table the change is small.)
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..materials import LOG10_DENSITY_RANGE, LOG10_E_RANGE, NU_RANGE


def uniform_variance(low: float, high: float, unit_low: float, unit_high: float) -> float:
    """Variance of a uniform draw on [low, high], in units where [unit_low, unit_high] spans 2 (−1 to 1)."""
    width = 2.0 * (high - low) / (unit_high - unit_low)
    return width * width / 12.0


def part_floor(part) -> np.ndarray:
    """(3,) variance of a part's (log10 E, ν, log10 ρ) label draw in normalised units (a PartSpec)."""
    return np.array([
        uniform_variance(math.log10(part.E_pa[0]), math.log10(part.E_pa[1]), *LOG10_E_RANGE),
        uniform_variance(part.nu[0], part.nu[1], *NU_RANGE),
        uniform_variance(math.log10(part.density_kg_m3[0]), math.log10(part.density_kg_m3[1]),
                         *LOG10_DENSITY_RANGE),
    ])


def record_floor_sums(record: dict, table: dict) -> tuple[np.ndarray, int] | None:
    """(Σ over the object's Gaussians of their part's floor (3,), Gaussian count) for one label record;
    its floor there is the first entry over the second. A pair (dataset/pairs.py) adds its partner's parts,
    a floor (dataset/floor.py) its Gaussians with constant labels (no spread). None when the record names a
    class or part `table` lacks or holds a value outside its range (made with another table)."""
    sums, count = np.zeros(3), 0
    partner = record.get("partner")
    for rec in [record] + ([partner] if isinstance(partner, dict) else []):
        spec = table.get(rec.get("class"))
        if spec is None:
            return None
        for part in rec.get("parts", []):
            try:
                spec_part = spec.part(part["name"])
            except KeyError:
                return None
            if not _drawn_from(spec_part, part):
                return None
            n = int(part.get("count", 0))
            sums += part_floor(spec_part) * n
            count += n
    floor = record.get("floor")
    if isinstance(floor, dict):
        count += int(floor.get("count", 0))
    return sums, count


def split_floor(data_dir: str | Path, split: str = "test", limit: int | None = None,
                table: dict | None = None) -> dict | None:
    """The label floor of a generated split, weighted per Gaussian like `pixie evaluate`'s table:
    {"floor_log_E", "floor_nu", "floor_log_rho", "floor_avg", "by_object_class": {category: floor_avg}}.

    Uses each object's label record (class, parts, their values and Gaussian counts) and the class
    table (`table`, default: the installed one). None when a record names a class or part the table
    lacks, or holds a value outside the table's range: the dataset was made with another table
    (`pixie generate --table`), and there is no floor to state.
    """
    from ..dataset.labels import load_class_table
    from ..dataset.loader import list_objects
    from ..errors import read_json_file

    table = load_class_table() if table is None else table
    by_class: dict[str, list] = {}  # category -> [sum of count × floor (3,), Gaussian count]
    for path in list_objects(data_dir, split)[: limit or None]:
        record = read_json_file(Path(path).with_suffix(".json"), "a label record")
        sums = record_floor_sums(record, table)
        if sums is None:
            return None
        # everything counted under the first object's category, as `pixie evaluate` counts it
        total = by_class.setdefault(record.get("class"), [np.zeros(3), 0])
        total[0] += sums[0]
        total[1] += sums[1]
    count = sum(n for _, n in by_class.values())
    if count == 0:
        return None
    mean = sum(s for s, _ in by_class.values()) / count
    return {"floor_log_E": float(mean[0]), "floor_nu": float(mean[1]), "floor_log_rho": float(mean[2]),
            "floor_avg": float(mean.mean()),
            "by_object_class": {k: float((s / max(n, 1)).mean()) for k, (s, n) in sorted(by_class.items())}}


def _drawn_from(spec_part, part: dict) -> bool:
    """Whether a record's part values (E Pa, ν, density kg/m³) lie within the table part's ranges."""
    try:
        return all(lo <= float(part[key]) <= hi for key, (lo, hi) in
                   (("E", spec_part.E_pa), ("nu", spec_part.nu), ("density", spec_part.density_kg_m3)))
    except (KeyError, TypeError, ValueError):
        return False
