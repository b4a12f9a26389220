"""Honest ranking: which runner-up effects the data cannot tell apart from the best one.

ΔBIC treats the n residual coordinates as independent. They are not: the residual a fitted
effect leaves is systematic — smooth over a whole track — and part of it is solver error (the
floor). Counting each track coordinate as ONE independent sample (n_eff = n / T for T frames),
the SSE of the best candidate has a standard deviation of about SSE_best·√(2T/n) (a χ² with
n_eff degrees of freedom, scaled by T). A runner-up is called indistinguishable when its SSE
exceeds the best's by less than 3 such standard deviations plus the squared solver error
n·f² it could absorb differently (floor.py), and it is itself significant.

`SEPARATE` says, for pairs that are often confused, what measurement would separate them.
"""
from __future__ import annotations

import math

from .score import Scored

SIGMAS = 3.0

# frozenset of two effect names → what measurement separates them
SEPARATE: dict[frozenset, str] = {
    frozenset({"viscous_damping", "air_drag"}):
        "drag grows with speed squared, damping linearly: track a faster throw (or a slow one) and compare "
        "the deceleration at high and low speed",
    frozenset({"viscous_damping", "ground_friction"}):
        "friction acts only in contact: track the flight before landing (damping slows it, friction does not)",
    frozenset({"air_drag", "ground_friction"}):
        "friction acts only in contact: track the flight before landing (drag slows it, friction does not)",
    frozenset({"wind", "ground_friction"}):
        "a constant push acts in flight too and keeps acting at rest: track the flight and a longer rest",
    frozenset({"wind", "air_drag"}):
        "drag opposes the velocity, wind has a fixed direction: toss in another direction",
    frozenset({"wind", "viscous_damping"}):
        "damping opposes the velocity, wind has a fixed direction: toss in another direction",
    frozenset({"part_stiffness", "part_density"}):
        "stiffness sets the wobble frequency, density also the static sag and the load on other parts: "
        "measure the resting deformation, or weigh the part",
    frozenset({"part_stiffness", "plastic_yield"}):
        "yield leaves a permanent set after unloading: track the object longer after the impact",
    frozenset({"part_density", "plastic_yield"}):
        "yield leaves a permanent set after unloading: track the object longer after the impact",
    frozenset({"anchored_part", "ground_friction"}):
        "an anchored part never lifts off: track a throw in which it should leave the ground",
}


def separation_hint(a: str, b: str) -> str:
    """What measurement would tell effect `a` from effect `b`."""
    if a == b:
        return "the same effect on another part: track more points on each part"
    return SEPARATE.get(frozenset({a, b}),
                        "track the motion longer, or in a second throw in another direction or speed")


def margin(best: Scored, n: int, frames: int, floor_per_coordinate: float = 0.0) -> float:
    """SSE difference below which a runner-up is indistinguishable from `best` (units²)."""
    sampling = SIGMAS * best.sse * math.sqrt(2.0 * max(frames, 1) / max(n, 1))
    return sampling + n * floor_per_coordinate ** 2


def ambiguous_with(ranking: list[Scored], n: int, frames: int, floor_per_coordinate: float = 0.0) -> list[Scored]:
    """Significant runner-ups whose fit is within `margin` of the best one (best first)."""
    if not ranking or not ranking[0].significant:
        return []
    best = ranking[0]
    m = margin(best, n, frames, floor_per_coordinate)
    return [s for s in ranking[1:] if s.significant and s.sse - best.sse < m
            and (s.effect, s.part) != (best.effect, best.part)]
