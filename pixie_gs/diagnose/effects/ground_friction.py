"""Ground friction: the Coulomb coefficient μ of the ground contact differs from the model's.

Physical meaning: the object slides further (μ too high in the model) or stops sooner
(μ too low) than simulated once it touches the ground. Sets the scene's `ground.friction`.
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Effect, EffectContext, Param


@dataclass
class GroundFriction(Effect):
    def params(self, context: EffectContext):
        base = float(context.scene.ground.friction)
        probe = base + 0.5 if base < 1.0 else base * 0.5
        return (Param("mu", "", 0.0, 3.0, log=False, probe=probe, off=base),)

    def apply(self, scene, cloud, part, values):
        scene = self.edited(scene)
        scene.ground.friction = float(values["mu"])
        return scene, cloud


EFFECT = GroundFriction(
    name="ground_friction",
    doc=" ".join(__doc__.split()),
    params_=(Param("mu", "", 0.0, 3.0, log=False, probe=1.0),),
)
