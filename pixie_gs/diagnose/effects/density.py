"""A part's density mis-estimated: its density ρ is really s·ρ (s dimensionless).

Physical meaning: one part is heavier or lighter than annotated, so it loads the parts that
carry it more or less (a heavier head bends its stem further). Sets
`part_overrides[part].density_scale` (baked into the `.ply` attribute `density`).
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Effect, Param


@dataclass
class PartDensity(Effect):
    def apply(self, scene, cloud, part, values):
        scene = self.edited(scene)
        o = self.override(scene, part)
        o.density_scale = float(o.density_scale) * float(values["density_scale"])
        return scene, cloud


EFFECT = PartDensity(
    name="part_density",
    doc=" ".join(__doc__.split()),
    per_part=True,
    kind="material",
    params_=(Param("density_scale", "", 0.05, 20.0, log=True, probe=2.0, off=1.0, extra_probes=(4.0, 0.4)),),
)
