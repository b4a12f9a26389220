"""Quadratic air drag: a = −k·|v|·v with k (1/m) — force grows with the square of speed.

Physical meaning: aerodynamic drag of a fast-moving or light, large-area object (leaves,
paper, foam) that a vacuum simulation omits. Adds k to the scene's `air_drag` key.
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Effect, Param


@dataclass
class QuadraticAirDrag(Effect):
    def apply(self, scene, cloud, part, values):
        scene = self.edited(scene)
        scene.air_drag = float(scene.air_drag) + float(values["k_per_m"])
        return scene, cloud


EFFECT = QuadraticAirDrag(
    name="air_drag",
    doc=" ".join(__doc__.split()),
    params_=(Param("k_per_m", "1/m", 0.01, 30.0, log=True, probe=1.0, off=0.0),),
)
