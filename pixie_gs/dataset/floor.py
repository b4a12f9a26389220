"""A floor under a generated object (issue 12: training splats with "some background (ground, table)").

A capture of a thing on a table or on the ground holds that surface too. `pixie annotate` finds and
removes it first (prepare: docs/prepare.md) in most scenes, but where it does not, the floor enters the
network's grid, which no generated object had: benchmarks/bench_pairs.py --floor measured the plain path
falling from 0.78 to 0.60 of each object's Gaussians right. `with_floor` stands an object on a floor disc
of flat Gaussians labelled as `prepare` writes ground (stationary, rigid), drawn from its own RNG.
"""
from __future__ import annotations

import numpy as np

from ..annotate import STATIONARY, STATIONARY_DENSITY, STATIONARY_E_PA, STATIONARY_NU
from ..splat import SplatCloud, rgb_to_sh_dc

FLOOR_SHARE = (0.1, 0.4)  # floor Gaussians per object Gaussian
FLOOR_REACH = (1.0, 2.0)  # disc radius, × the object's footprint half-diagonal (about its footprint centre)
FLOOR_COLOURS = [(0.45, 0.45, 0.43), (0.60, 0.45, 0.30), (0.85, 0.84, 0.80), (0.25, 0.25, 0.27),
                 (0.40, 0.50, 0.30)]  # concrete, wood, tile, dark table, lawn
FLOOR_PART_ID = -1  # part id of floor Gaussians (no class table part)


def floor_under(cloud: SplatCloud, rng: np.random.Generator, share: float | None = None,
                reach: float | None = None) -> SplatCloud:
    """A floor disc (z up, metres) under `cloud`: centred under its footprint, at its lowest Gaussian
    centre, `share` × its Gaussian count (drawn from FLOOR_SHARE when None), radius `reach` × the
    footprint's half-diagonal (FLOOR_REACH when None). Flat Gaussians (10× thinner than wide) about one
    spacing wide, opacities drawn from the object's own, one colour with noise; labels as `prepare`
    writes ground; every other property of `cloud` present (zero, normals +z), same SH degree."""
    lo, hi = cloud.bounds()
    n = max(16, int(round(len(cloud) * (rng.uniform(*FLOOR_SHARE) if share is None else share))))
    radius = float(np.linalg.norm(hi[:2] - lo[:2])) / 2 * (rng.uniform(*FLOOR_REACH) if reach is None else reach)
    radius = max(radius, 1e-3)
    centre = 0.5 * (lo + hi)
    r, angle = radius * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    points = np.column_stack([centre[0] + r * np.cos(angle), centre[1] + r * np.sin(angle), np.full(n, lo[2])])
    spacing = radius * np.sqrt(np.pi / n)
    width = spacing * rng.uniform(0.6, 1.2)
    colour = np.asarray(FLOOR_COLOURS[int(rng.integers(len(FLOOR_COLOURS)))]) + rng.normal(0, 0.04, 3)
    rgb = np.clip(colour + rng.normal(0, 0.03, (n, 3)), 0, 1).astype(np.float32)
    floor = SplatCloud.from_arrays(points, log_scales=np.log(np.tile([width, width, width / 10], (n, 1))),
                                   opacity_logits=rng.choice(cloud.opacity_logits, n),
                                   sh_dc=rgb_to_sh_dc(rgb)).with_sh_degree(cloud.sh_degree)
    labels = {"material_id": STATIONARY, "E": STATIONARY_E_PA, "nu": STATIONARY_NU, "density": STATIONARY_DENSITY,
              "part_id": FLOOR_PART_ID, "nz": 1.0}
    for name, values in cloud.extras.items():
        floor.set(name, np.full(n, labels.get(name, 0), values.dtype), values.dtype)
    floor.property_order = list(cloud.property_order)
    return floor


def with_floor(cloud: SplatCloud, rng: np.random.Generator, **kw) -> tuple[SplatCloud, int]:
    """(`cloud` standing on `floor_under(cloud, rng, **kw)`, the floor's Gaussian count); the floor's
    Gaussians come last, so the object's keep their indices."""
    floor = floor_under(cloud, rng, **kw)
    return SplatCloud.concatenate([cloud, floor]), len(floor)


def floor_record(count: int) -> dict:
    """The `floor` entry of an object's label record: its Gaussian count, part id and (constant) labels."""
    return {"count": int(count), "part_id": FLOOR_PART_ID, "material_id": STATIONARY, "E": STATIONARY_E_PA,
            "nu": STATIONARY_NU, "density": STATIONARY_DENSITY}
