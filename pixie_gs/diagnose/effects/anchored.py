"""A part that is actually anchored: it is held fixed in place (glued, bolted, rooted).

Physical meaning: the measured part does not move although the model lets it fall or slide;
parts attached to it swing about it. No continuous parameter. Sets
`part_overrides[part].fixed = true`.
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Effect


@dataclass
class AnchoredPart(Effect):
    def apply(self, scene, cloud, part, values):
        scene = self.edited(scene)
        self.override(scene, part).fixed = True
        return scene, cloud


EFFECT = AnchoredPart(
    name="anchored_part",
    doc=" ".join(__doc__.split()),
    per_part=True,
    kind="material",
    params_=(),
)
