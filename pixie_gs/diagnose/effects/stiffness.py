"""A part's stiffness mis-estimated: its Young's modulus E is really s·E (s dimensionless).

Physical meaning: the annotated E of one part is off — it sags, bounces or vibrates more
(softer) or less (stiffer) than simulated. Sets `part_overrides[part].E_scale` (baked into the
`.ply` attribute `E` in the written model).
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Effect, Param


@dataclass
class PartStiffness(Effect):
    def apply(self, scene, cloud, part, values):
        scene = self.edited(scene)
        o = self.override(scene, part)
        o.E_scale = float(o.E_scale) * float(values["E_scale"])
        return scene, cloud


EFFECT = PartStiffness(
    name="part_stiffness",
    doc=" ".join(__doc__.split()),
    per_part=True,
    kind="material",
    params_=(Param("E_scale", "", 0.01, 100.0, log=True, probe=0.5, off=1.0, extra_probes=(0.25, 2.5)),),
)
