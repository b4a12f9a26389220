"""PreparedScene: what preparation decided about a capture, and its sidecar JSON."""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from .updir import rotation_to_z

# Per-Gaussian `role` codes (uint8 property written by prepare; documented in docs/prepare.md).
ROLE_OBJECT, ROLE_BACKGROUND, ROLE_GROUND, ROLE_FLOATER = 0, 1, 2, 3
ROLE_NAMES = {ROLE_OBJECT: "object", ROLE_BACKGROUND: "background", ROLE_GROUND: "ground",
              ROLE_FLOATER: "floater"}


@dataclass
class PreparedObject:
    """One object: id, Gaussian count, robust box (0.5–99.5 percentiles) in file coordinates
    (`box_file`), the same in the up frame (`box_up`: rotated so up is +z), and the box used to
    normalise it into the unit cube (`fit_box_up`, up frame). Lengths in file units."""

    object_id: int
    count: int
    box_file: list[list[float]]
    box_up: list[list[float]]
    fit_box_up: list[list[float]]


@dataclass
class PreparedScene:
    """Decisions of `prepare_cloud`. `up`: unit vector in file coordinates; `up_source`: "given"
    or "auto"; `up_method`: ground-plane / flat-base / shape / given; `angle_from_axis_deg` to
    `nearest_axis`; `ground_height`: up·x of the floor (file units, None when no ground);
    `ground_extent_up`: its [[x0, y0], [x1, y1]] in the up frame; `counts`: Gaussians per role."""

    up: list[float]
    up_source: str
    up_method: str
    up_confidence: float
    nearest_axis: str
    angle_from_axis_deg: float
    ground_height: float | None
    ground_extent_up: list[list[float]] | None
    objects: list[PreparedObject] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    crop: str | None = None
    spacing: float = 0.0
    seconds: float = 0.0
    count: int = 0

    @property
    def up_vector(self) -> np.ndarray:
        return np.asarray(self.up, np.float64)

    def rotation(self) -> np.ndarray:
        """R (3,3) with R·up = +z: file coordinates → the up frame."""
        return rotation_to_z(self.up_vector)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["role_codes"] = {str(k): v for k, v in ROLE_NAMES.items()}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "PreparedScene":
        d = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        d["objects"] = [PreparedObject(**o) for o in d.get("objects", [])]
        return cls(**d)

    def write(self, path: str | Path) -> Path:
        """Write the sidecar JSON atomically."""
        path = Path(path)
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")
        return path

    def summary(self, name: str = "") -> str:
        """One terminal line: up, how it was found, ground, objects, counts per role."""
        up = ",".join(f"{c:.3f}" for c in self.up)
        ground = "no ground" if self.ground_height is None else f"ground at {self.ground_height:.3g}"
        counts = ", ".join(f"{v} {k}" for k, v in self.counts.items() if v)
        return (f"prepared {name + ': ' if name else ''}up ({up}) [{self.up_source}, {self.up_method}, "
                f"{self.angle_from_axis_deg:.1f}° from {self.nearest_axis}, confidence {self.up_confidence:.2f}]; "
                f"{ground}; {len(self.objects)} object(s); {counts}")


def sidecar_path(out_path: str | Path) -> Path:
    """OUT.prepare.json beside OUT (the suffix of OUT replaced)."""
    p = Path(out_path)
    return p.with_name(p.stem + ".prepare.json")
