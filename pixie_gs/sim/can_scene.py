"""A soda-can test scene: a thin lidded aluminium shell struck on its side by an impulse.

Why: the stiff-parts acceptance case (docs/simulate.md). Real aluminium (E 7e10 Pa, ν 0.33,
ρ 2700 kg/m³, von Mises yield 2e8 Pa) needs tens of thousands of substeps per frame; on a GPU it
runs at true stiffness and must dent and stay dented, on a CPU budget it runs as a rigid body.
Used by tests/test_sim_rigid.py and benchmarks/bench_can_dent.py.
"""
from __future__ import annotations

import numpy as np

from ..materials import METAL
from .particles import Particles
from .scene import Scene

CAN_RADIUS_M = 0.03
CAN_HEIGHT_M = 0.04
ALUMINIUM = {"E": 7e10, "nu": 0.33, "density": 2700.0, "material_id": METAL, "yield_stress": 2e8}


def soda_can(dx_m: float, dv_mps: float, stiff_parts: str, budget: int,
             held_back: bool = True) -> tuple[Particles, Scene, np.ndarray]:
    """The can on a grid of spacing dx_m (wall and lids one cell thick, two particle layers),
    floating (no gravity, no ground), part id 0, its back (x > R/2) held in place when
    `held_back` (a can against a wall). At t = 0 the patch of its −x wall (|y| < 0.4 R, middle
    40 % of the height) gets +dv_mps along x. Returns the particles, the scene
    (solver.stiff_parts and max_substeps_per_frame as given) and the mask of the measured wall
    band (middle 40 %, |y| < 0.2 R: its x extent is the diameter along the blow)."""
    R, H = CAN_RADIUS_M, CAN_HEIGHT_M
    side = 2 * R + 12 * dx_m + 0.02  # the can, 3 boundary cells and some room on each side
    grid = int(round(side / dx_m))
    side = grid * dx_m
    band = (0.3 * H, 0.7 * H)
    keys = {
        "domain": {"size_m": side, "grid": grid, "origin": [-side / 2, -side / 2, H / 2 - side / 2]},
        "ground": {"enabled": False}, "gravity": [0, 0, 0],
        "impulses": [{"time_s": 0.0, "velocity_change": [dv_mps, 0, 0],
                      "region": {"min": [-R - 0.01, -0.4 * R, band[0]], "max": [-0.6 * R, 0.4 * R, band[1]]}}],
        "solver": {"max_substeps_per_frame": budget, "stiff_parts": stiff_parts}}
    if held_back:
        keys["fixed"] = [{"region": {"min": [0.5 * R, -R - 0.01, -0.01], "max": [R + 0.01, R + 0.01, H + 0.01]}}]
    scene = Scene.from_dict(keys)

    def shell(x: np.ndarray) -> np.ndarray:
        r = np.hypot(x[:, 0], x[:, 1])
        return (r <= R) & ((r >= R - dx_m) | (x[:, 2] <= dx_m) | (x[:, 2] >= H - dx_m))

    p = Particles.lattice((-R, -R, 0.0), (R, R, H), dx_m / 2, inside=shell, part_id=0, **ALUMINIUM)
    measured = (p.x[:, 2] >= band[0]) & (p.x[:, 2] <= band[1]) & (np.abs(p.x[:, 1]) < 0.2 * R)
    return p, scene, measured


def diameter_along_blow(x: np.ndarray, measured: np.ndarray) -> float:
    """x extent (m) of the measured wall band: the can's diameter along the blow."""
    return float(np.ptp(x[measured, 0]))
