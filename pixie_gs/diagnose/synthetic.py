"""Synthetic measurements: simulate a model WITH an effect it normally lacks, then track a
sparse, noisy subset of its Gaussians — the test bed of the discrepancy loop (tests, example,
benchmark). The hidden effect is applied with the library's own `Effect.apply`.
"""
from __future__ import annotations

import numpy as np

from ..splat import SplatCloud
from .effects import get_effect


def hide_effect(scene, cloud: SplatCloud, effect: str | None, part: int | None = None,
                values: dict[str, float] | None = None):
    """(scene', cloud') = the model with `effect` (None: unchanged) added at `values`."""
    if effect is None:
        return scene, cloud
    return get_effect(effect).apply(scene, cloud, part, dict(values or {}))


def track_subset(x: np.ndarray, fraction: float = 0.05, noise_m: float = 0.0, seed: int = 0,
                 min_points: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Pick `fraction` of the Gaussians (at least `min_points`) and add white noise of std
    `noise_m` (splat units) per coordinate → (ids (M,), noisy tracks (T,M,3))."""
    rng = np.random.default_rng(seed)
    n = x.shape[1]
    m = min(n, max(min_points, int(round(fraction * n))))
    ids = np.sort(rng.choice(n, m, replace=False))
    tracks = x[:, ids].astype(np.float64) + rng.normal(0.0, noise_m, (x.shape[0], m, 3))
    return ids, tracks


def make_measurement(cloud: SplatCloud, scene, frames: int, fps: float, effect: str | None = None,
                     part: int | None = None, values: dict[str, float] | None = None,
                     fraction: float = 0.05, noise_m: float = 0.0, seed: int = 0, device: str = "auto",
                     fill: bool = False) -> dict[str, np.ndarray]:
    """Arrays of a measured `.npz` ({t, x, ids}) made with `effect` hidden from the model."""
    from ..progress import is_quiet, set_quiet
    from ..sim.run import simulate

    hidden_scene, hidden_cloud = hide_effect(scene, cloud, effect, part, values)
    quiet = is_quiet()
    set_quiet(True)
    try:
        traj = simulate(hidden_cloud, hidden_scene, frames, fps, device=device, fill=fill)
    finally:
        set_quiet(quiet)
    ids, x = track_subset(traj.x, fraction, noise_m, seed)
    return {"t": traj.t, "x": x, "ids": ids}


# ---------------------------------------------------------------------------------- test beds
def two_part_block(n: int = 500, seed: int = 0, E_body_pa: float = 2e3, E_head_pa: float = 4e3,
                   density_body: float = 150.0, density_head: float = 100.0, aspect: float = 1.0) -> SplatCloud:
    """A soft jelly block (part 0, 0.2 × 0.2 × 0.1·aspect) carrying a smaller head on top (part 1,
    0.1 × 0.1 × 0.1): a small two-part object whose parts load each other (splat units = m)."""
    from ..materials import JELLY

    rng = np.random.default_rng(seed)
    nb = int(round(0.6 * n))
    nh = n - nb
    hb = 0.1 * aspect
    body = rng.uniform([-0.1, -0.1, 0.0], [0.1, 0.1, hb], (nb, 3))
    head = rng.uniform([-0.05, -0.05, hb], [0.05, 0.05, hb + 0.1], (nh, 3))
    part = np.r_[np.zeros(nb), np.ones(nh)].astype(np.int32)
    rgb = np.where(part[:, None] == 0, [0.85, 0.45, 0.3], [0.3, 0.55, 0.85])
    cloud = SplatCloud.from_arrays(np.concatenate([body, head]), rgb=rgb,
                                   log_scales=np.full((n, 3), np.log(0.008), np.float32))
    cloud.set_materials(np.full(n, JELLY), np.where(part == 0, E_body_pa, E_head_pa), np.full(n, 0.35),
                        np.where(part == 0, density_body, density_head))
    cloud.set("part_id", part, np.int32)
    return cloud


def toss_scene(size_m: float = 0.3, grid: int = 20, friction: float = 0.3, speed_m_s: float = 1.5):
    """A scene that exercises every effect in a short time: the object is tossed sideways and
    up at t = 0 (flight: drag, damping, wind), lands (impact: stiffness, density, yield) and
    slides on the ground (friction)."""
    from ..sim.scene import Scene

    return Scene.from_dict({
        "object": {"size_m": size_m, "position": [-0.15, 0.0, 0.1]},
        "domain": {"size_m": 1.0, "grid": grid},
        "ground": {"friction": friction},
        "impulses": [{"time_s": 0.0, "velocity_change": [speed_m_s, 0.0, 0.66 * speed_m_s]}],
    })


# Hidden effects used by the tests, the example and the benchmark: (effect, part, weak, strong).
HIDDEN_EFFECTS: list[tuple[str, int | None, dict[str, float], dict[str, float]]] = [
    ("viscous_damping", None, {"rate_per_s": 1.0}, {"rate_per_s": 3.0}),
    ("air_drag", None, {"k_per_m": 1.0}, {"k_per_m": 3.0}),
    ("ground_friction", None, {"mu": 0.8}, {"mu": 1.5}),
    ("wind", None, {"ax_m_s2": 0.0, "ay_m_s2": 1.5, "az_m_s2": 0.0}, {"ax_m_s2": -2.0, "ay_m_s2": 2.0, "az_m_s2": 0.0}),
    ("part_stiffness", 1, {"E_scale": 0.3}, {"E_scale": 0.15}),
    ("part_density", 1, {"density_scale": 3.0}, {"density_scale": 5.0}),
    ("plastic_yield", 0, {"yield_stress_pa": 40.0}, {"yield_stress_pa": 15.0}),
    ("anchored_part", 0, {}, {}),
]


# ---------------------------------------------------------------- independent-engine test bed
def independent_toss_scene(grid: int = 80):
    """The scene of the independent-engine fixtures (scripts/make_independent_tracks.py): the
    two-part block, 0.3 m, bottom centre at (−0.15, 0, 0.1) m, tossed at (1.2, 0, 0.8) m/s onto
    ground with μ = 0.3, in a 2 m domain (large enough that it never reaches a wall; grid 80:
    dx = 2.5 cm)."""
    from ..sim.scene import Scene

    return Scene.from_dict({
        "object": {"size_m": 0.3, "position": [-0.15, 0.0, 0.1]},
        "domain": {"size_m": 2.0, "grid": grid},
        "ground": {"friction": 0.3},
        "impulses": [{"time_s": 0.0, "velocity_change": [1.2, 0.0, 0.8]}],
    })


def in_millimetres(x: np.ndarray) -> np.ndarray:
    """Tracks as a tracker reporting millimetres would write them (splat units taken as metres)."""
    return np.asarray(x, np.float64) * 1000.0


def start_late(t: np.ndarray, x: np.ndarray, frames: int = 1, noise: float = 1e-3, seed: int = 0
               ) -> tuple[np.ndarray, np.ndarray]:
    """The camera started `frames` frames before the release: rest-pose frames are prepended and
    the measured clock runs `frames`/fps ahead of the simulation's (release at t = frames/fps)."""
    rng = np.random.default_rng(seed)
    dt = float(np.median(np.diff(t)))
    rest = x[:1] + rng.normal(0.0, noise, (frames,) + x.shape[1:])
    return np.arange(len(t) + frames) * dt, np.concatenate([rest, x])


def add_outlier_tracks(x: np.ndarray, fraction: float = 0.05, seed: int = 0, jump: float = 0.05
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Corrupt `fraction` of the tracks as trackers do: half get stuck on the background (stay
    where they were from a random frame on), half jump by `jump`–2·`jump` units to a wrong point.
    Returns (tracks, indices of the corrupted tracks)."""
    rng = np.random.default_rng(seed)
    x = np.array(x, np.float64)
    T, M = x.shape[:2]
    bad = np.sort(rng.choice(M, max(1, int(round(fraction * M))), replace=False))
    for j, m in enumerate(bad):
        f = int(rng.integers(2, max(3, T // 2)))
        if j % 2 == 0:
            x[f:, m] = x[f, m]
        else:
            direction = rng.normal(size=3)
            x[f:, m] += direction / np.linalg.norm(direction) * jump * rng.uniform(1.0, 2.0)
    return x, bad


def occlude(x: np.ndarray, fraction: float = 0.2, seed: int = 0) -> np.ndarray:
    """Visibility mask (T,M) with `fraction` of the (frame, point) observations lost in runs of a
    few frames (a tracker losing points behind the object); the first frame stays visible."""
    rng = np.random.default_rng(seed)
    T, M = x.shape[:2]
    vis = np.ones((T, M), bool)
    target = int(round(fraction * T * M))
    while (~vis).sum() < target:
        m = int(rng.integers(M))
        f = int(rng.integers(1, T))
        vis[f:f + int(rng.integers(2, 6)), m] = False
    return vis
