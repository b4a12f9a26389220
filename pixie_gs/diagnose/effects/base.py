"""What a candidate missing effect is: a named, documented model extension with few parameters.

An effect declares its parameters (bounds, units, whether to search them in log space), whether
it acts on one part of the object (`per_part`, the part chosen from the locate step), and
`apply(scene, cloud, part, values) -> (scene', cloud')`, which returns edited COPIES and never
touches its inputs. Scene effects edit scene keys (damping, air_drag, ground.friction, wind);
material effects edit `part_overrides` (baked into the `.ply` attributes by the report step).
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ...sim.scene import PartOverride, Scene
    from ...splat import SplatCloud


@dataclass(frozen=True)
class Param:
    """One fitted parameter: bounds [lo, hi] in `unit`, searched in log10 space when `log`.

    `off` is the value at which the effect vanishes (None when it has none inside the bounds);
    `probe` is the value tried first when screening candidates (with `off` it gives the
    sensitivity); `extra_probes` are further screening values for strongly non-linear effects.
    """

    name: str
    unit: str
    lo: float
    hi: float
    log: bool
    probe: float
    off: float | None = None
    extra_probes: tuple[float, ...] = ()

    def to_search(self, value: float) -> float:
        """Map a physical value to the search coordinate (log10 or identity)."""
        return math.log10(value) if self.log else float(value)

    def from_search(self, u: float) -> float:
        lo, hi = self.to_search(self.lo), self.to_search(self.hi)
        u = min(max(u, lo), hi)
        return 10.0 ** u if self.log else float(u)

    @property
    def search_bounds(self) -> tuple[float, float]:
        return self.to_search(self.lo), self.to_search(self.hi)


@dataclass(frozen=True)
class EffectContext:
    """What an effect may look at to choose its parameter bounds: the model and the target part."""

    scene: "Scene"
    cloud: "SplatCloud"
    part: int | None

    def part_mask(self) -> np.ndarray:
        if self.part is None or not self.cloud.has("part_id"):
            return np.ones(len(self.cloud), bool)
        return self.cloud.get("part_id") == self.part

    def part_median(self, attribute: str, default: float) -> float:
        if not self.cloud.has(attribute):
            return default
        values = self.cloud.get(attribute)[self.part_mask()]
        return float(np.median(values)) if len(values) else default


@dataclass
class Effect:
    """Base class of the effect library; subclasses fill the class attributes and `apply`."""

    name: str = ""
    doc: str = ""
    per_part: bool = False
    kind: str = "scene"          # "scene" (scene keys) or "material" (part attributes)
    params_: tuple[Param, ...] = field(default_factory=tuple)

    def params(self, context: EffectContext) -> tuple[Param, ...]:
        """Parameters with bounds for this model/part (override when bounds depend on the model)."""
        return self.params_

    def apply(self, scene: "Scene", cloud: "SplatCloud", part: int | None,
              values: dict[str, float]) -> tuple["Scene", "SplatCloud"]:
        raise NotImplementedError

    # helpers for subclasses ------------------------------------------------------------
    @staticmethod
    def edited(scene: "Scene") -> "Scene":
        """A deep copy of `scene` to edit."""
        return copy.deepcopy(scene)

    @staticmethod
    def override(scene: "Scene", part: int | None) -> "PartOverride":
        """The (created if missing) part override of `part` in `scene` (edit a copy!)."""
        from ...sim.scene import PartOverride

        if part is None:
            raise ValueError("a material effect needs a part")
        if part not in scene.part_overrides:
            scene.part_overrides[part] = PartOverride()
        return scene.part_overrides[part]

    def describe(self) -> dict:
        return {"name": self.name, "doc": self.doc, "per_part": self.per_part, "kind": self.kind,
                "params": [{"name": p.name, "unit": p.unit, "lo": p.lo, "hi": p.hi, "log": p.log}
                           for p in self.params_]}
