"""Which (category, part) a Gaussian belongs to: the target of the training-only part head.

Why: every part's E, ν and ρ are drawn inside its category's range independently of the splat
(bench_label_floor.py), so the regression targets tell a network which category it looks at only
through noise of the size of the label floor. The (category, part) identity itself is noise-free;
a head that must name it (`pixie train --part-weight W`) gives the shared features that signal.
Labels are "category/part" names of the class table, in its order (part ids 0 … P−1 per category).
"""
from __future__ import annotations

import numpy as np

MAX_PARTS = 3  # the most parts any category of the class table has (tests/test_part_labels.py checks it)
UNKNOWN_SLOT = MAX_PARTS  # a Gaussian's slot when its part id names no part (floors, unlabelled)
IGNORE = -1  # target of a voxel that belongs to no known (category, part)


def part_label_names() -> list[str]:
    """Every "category/part" of the class table, the part head's outputs in order."""
    from ..dataset.labels import load_class_table

    return [f"{name}/{part.name}" for name, spec in load_class_table().items()
            for part in sorted(spec.parts, key=lambda p: p.part_id)]


def part_slots(part_id: np.ndarray | None, count: int) -> np.ndarray:
    """(M,) int64 slot of each Gaussian: its part id when in 0 … MAX_PARTS−1, else UNKNOWN_SLOT."""
    if part_id is None:
        return np.full(count, UNKNOWN_SLOT, dtype=np.int64)
    pid = np.asarray(part_id, dtype=np.int64)
    return np.where((pid >= 0) & (pid < MAX_PARTS), pid, UNKNOWN_SLOT)


def slot_table(class_name: str, names: list[str]) -> list[int]:
    """(MAX_PARTS + 1,) the label index of each slot for an object of `class_name` (IGNORE for slots that
    name no part of it, for the unknown slot, and for a category the label list lacks)."""
    table = [IGNORE] * (MAX_PARTS + 1)
    prefix = class_name + "/"
    own = [i for i, n in enumerate(names) if n.startswith(prefix)]
    for slot, index in enumerate(own[:MAX_PARTS]):
        table[slot] = index
    return table
