"""Viscous damping: every particle loses velocity at a rate c (1/s), a = −c·v.

Physical meaning: internal friction and energy loss the elastic model lacks — oscillations die
out and free motion slows exponentially. Adds c to the scene's `damping` key.
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Effect, Param


@dataclass
class ViscousDamping(Effect):
    def apply(self, scene, cloud, part, values):
        scene = self.edited(scene)
        scene.damping = float(scene.damping) + float(values["rate_per_s"])
        return scene, cloud


EFFECT = ViscousDamping(
    name="viscous_damping",
    doc=" ".join(__doc__.split()),
    params_=(Param("rate_per_s", "1/s", 0.01, 30.0, log=True, probe=1.0, off=0.0),),
)
