"""Wind / unmodelled external force: a constant body acceleration vector a (m/s², world axes).

Physical meaning: a steady push the model lacks — wind, a slope, a magnet, a mis-levelled
gravity direction. Appends a `wind` entry with that acceleration acting everywhere, always.
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Effect, Param


@dataclass
class ConstantWind(Effect):
    def apply(self, scene, cloud, part, values):
        from ...sim.scene import Wind

        scene = self.edited(scene)
        accel = (float(values["ax_m_s2"]), float(values["ay_m_s2"]), float(values["az_m_s2"]))
        scene.wind = list(scene.wind) + [Wind(acceleration=accel)]
        return scene, cloud


EFFECT = ConstantWind(
    name="wind",
    doc=" ".join(__doc__.split()),
    params_=tuple(Param(f"a{axis}_m_s2", "m/s²", -20.0, 20.0, log=False, probe=0.5, off=0.0)
                  for axis in "xyz"),
)
