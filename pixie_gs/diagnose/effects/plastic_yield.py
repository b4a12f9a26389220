"""Plastic yield of a part: beyond a von Mises yield stress σ_y (Pa) it keeps a permanent set.

Physical meaning: the part bends or dents and does not spring back (soft metal, clay, a
kinked stem). Sets `part_overrides[part].yield_stress_pa`; bounds scale with the part's E
(yield strains 1e-5 … 0.3).
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Effect, EffectContext, Param


@dataclass
class PartPlasticYield(Effect):
    def params(self, context: EffectContext):
        E = context.part_median("E", 1e5)
        scale = float(context.scene.part_overrides.get(context.part).E_scale) \
            if context.part in context.scene.part_overrides else 1.0
        E = E * scale
        return (Param("yield_stress_pa", "Pa", 1e-5 * E, 0.3 * E, log=True, probe=3e-3 * E, off=None,
                      extra_probes=(3e-2 * E, 3e-4 * E)),)

    def apply(self, scene, cloud, part, values):
        scene = self.edited(scene)
        self.override(scene, part).yield_stress_pa = float(values["yield_stress_pa"])
        return scene, cloud


EFFECT = PartPlasticYield(
    name="plastic_yield",
    doc=" ".join(__doc__.split()),
    per_part=True,
    kind="material",
    params_=(Param("yield_stress_pa", "Pa", 1.0, 1e9, log=True, probe=1e3),),
)
