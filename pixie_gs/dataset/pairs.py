"""Two generated objects of different categories side by side in one splat (issue 12).

Every generated object used to fill its grid alone, while a real capture often holds several things
(a plant in a frame, a can beside a vase). benchmarks/bench_pairs.py measured that every checkpoint
then spreads one material over two touching objects. A *pair* is the training answer: object A and a
partner B of another category, each built as usual from its own seed, stood on one ground with their
footprints touching. Labels stay per Gaussian, so each object keeps its own parts and values.
"""
from __future__ import annotations

import numpy as np

from ..splat import SplatCloud
from .assemble import build_object, extent_record
from .labels import ClassSpec
from .leftovers import LEFTOVER_OBJECT_SHARE
from .lighting import LIGHTING_OBJECT_SHARE

PAIR_GAP = (-0.1, 0.2)  # gap between the footprints, as a share of the smaller one (negative: they overlap)
PARTNER_PART_OFFSET = 100  # added to the partner's part ids, so the two objects' parts never share an id
MIN_PAIR_GAUSSIANS = 200  # each object of a pair gets half the budget; build_object wants ≥ 100


def side_by_side(a: SplatCloud, b: SplatCloud, rng: np.random.Generator) -> tuple[SplatCloud, np.ndarray]:
    """`a` and `b` (z up, metres) on one ground: b's footprint moved beside a's in a random horizontal
    direction until they touch, with a gap of PAIR_GAP × the smaller footprint (along that direction).
    Returns (the joined cloud, a's Gaussians first; b's shift (3,) in metres). SH degrees are matched
    by zero coefficients first (`SplatCloud.with_sh_degree`)."""
    lo_a, hi_a = a.bounds()
    lo_b, hi_b = b.bounds()
    angle = rng.uniform(0.0, 2.0 * np.pi)
    direction = np.array([np.cos(angle), np.sin(angle), 0.0])
    half_a = 0.5 * float((hi_a - lo_a)[:2] @ np.abs(direction[:2]))
    half_b = 0.5 * float((hi_b - lo_b)[:2] @ np.abs(direction[:2]))
    gap = rng.uniform(*PAIR_GAP) * 2.0 * min(half_a, half_b)
    shift = 0.5 * (lo_a + hi_a) - 0.5 * (lo_b + hi_b) + direction * (half_a + half_b + gap)
    shift[2] = lo_a[2] - lo_b[2]  # the same ground height
    degree = max(a.sh_degree, b.sh_degree)
    a, moved = a.with_sh_degree(degree), b.with_sh_degree(degree)
    moved.means = (moved.means + shift).astype(np.float32)
    return SplatCloud.concatenate([a, moved]), shift


def pair_seeds(pair_seed: int) -> tuple[int, int, int]:
    """(object A's seed, partner B's seed, placement seed), 64-bit each, from one pair seed."""
    state = np.random.SeedSequence(int(pair_seed)).generate_state(6, np.uint32)
    return tuple(int(state[2 * k]) << 32 | int(state[2 * k + 1]) for k in range(3))


def build_pair(spec: ClassSpec, partner: ClassSpec, pair_seed: int, n_gaussians: int, realistic: bool = False,
               leftover_share: float = LEFTOVER_OBJECT_SHARE,
               lighting_share: float = LIGHTING_OBJECT_SHARE) -> tuple[SplatCloud, dict]:
    """Object `spec` and a `partner` side by side, about `n_gaussians` Gaussians in all (half each;
    `realistic`, `leftover_share` and `lighting_share` as in `build_object`, for both).

    Returns the joined cloud (labels per Gaussian; the partner's part ids + PARTNER_PART_OFFSET) and
    A's index record with the pair's Gaussian count and bounds and a `partner` entry holding B's own
    record, its part-id offset and its shift (m)."""
    if spec.name == partner.name:
        raise ValueError(f"a pair needs two categories (got '{spec.name}' twice)")
    if n_gaussians < MIN_PAIR_GAUSSIANS:
        raise ValueError(f"a pair needs ≥ {MIN_PAIR_GAUSSIANS} Gaussians (got {n_gaussians})")
    seed_a, seed_b, seed_place = pair_seeds(pair_seed)
    a, record = build_object(spec, seed_a, n_gaussians // 2, realistic, leftover_share, lighting_share)
    b, partner_record = build_object(partner, seed_b, n_gaussians - n_gaussians // 2, realistic, leftover_share,
                                     lighting_share)
    b.set("part_id", (b.get("part_id") + PARTNER_PART_OFFSET).astype(np.int32), np.int32)
    cloud, shift = side_by_side(a, b, np.random.default_rng(seed_place))
    partner_record = {**partner_record, "part_id_offset": PARTNER_PART_OFFSET,
                      "shift_m": [round(float(v), 5) for v in shift]}
    return cloud, {**record, "seed": int(pair_seed), **extent_record(cloud), "partner": partner_record}
