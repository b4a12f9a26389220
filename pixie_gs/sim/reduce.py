"""Per-frame particle statistics reduced on the device: the divergence guard and the CFL inputs.

One kernel reads x, v, F and Jp once and reduces them into a handful of numbers — the fastest
moving particle (m/s), the fastest hardened elastic wave among moving snow (m/s) and, per
material, how many particles are non-finite or ran away — so a frame copies 2 small arrays back
instead of the whole particle state. `reference_stats` is the same test in plain numpy (the
guard as it was first written), kept to check the kernel against.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

N_MATERIALS = 7  # pixie_gs.materials ids 0..6
SNOW_ID = 5  # pixie_gs.materials.SNOW (a literal: kernels cannot read module globals of other modules)
REDUCE_THREADS = 16384  # threads of the reduction; each one folds a strided share of the particles


@dataclass
class FrameStats:
    """max_speed_mps: fastest moving particle; max_snow_wave_mps: fastest hardened P-wave among
    moving snow (0 without snow); bad_per_material (7,): particles that failed the guard, by id."""

    max_speed_mps: float
    max_snow_wave_mps: float
    bad_per_material: np.ndarray

    @property
    def bad(self) -> int:
        return int(self.bad_per_material.sum())


@wp.func
def fails_guard(xp: wp.vec3, speed: float, Fp: wp.mat33, v_limit: float, max_stretch: float) -> bool:
    """The divergence guard's test for one particle: non-finite x/v/F, speed (m/s) > v_limit,
    ‖F‖ > max_stretch or det F ≤ 1/max_stretch (reference_stats is its numpy twin)."""
    norm = wp.sqrt(wp.ddot(Fp, Fp))
    J = wp.determinant(Fp)
    finite = wp.isfinite(xp[0]) and wp.isfinite(xp[1]) and wp.isfinite(xp[2])
    finite = finite and wp.isfinite(speed) and wp.isfinite(norm) and wp.isfinite(J)
    return (not finite) or speed > v_limit or norm > max_stretch or not (J > 1.0 / max_stretch)


@wp.kernel
def particle_stats(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), F: wp.array(dtype=wp.mat33),
                   Jp: wp.array(dtype=float), material: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
                   wave_c: wp.array(dtype=float), snow_hardening: float, v_limit: float, max_stretch: float,
                   n: int, stride: int, maxima: wp.array(dtype=float), bad: wp.array(dtype=wp.int32)):
    """maxima[0] ← max speed of moving particles, maxima[1] ← max c·√exp(ξ(1−Jp)) of moving snow;
    bad[material] += 1 per particle with non-finite x/v/F, speed > v_limit, ‖F‖ > max_stretch or
    det F ≤ 1/max_stretch (the numpy guard's test, reference_stats)."""
    t = wp.tid()  # thread t folds particles t, t + stride, t + 2·stride, ...
    speed_max = float(0.0)
    wave_max = float(0.0)
    p = t
    while p < n:
        speed = wp.length(v[p])
        if fails_guard(x[p], speed, F[p], v_limit, max_stretch):
            wp.atomic_add(bad, material[p], 1)
        elif fixed[p] == 0:
            speed_max = wp.max(speed_max, speed)
            if material[p] == SNOW_ID:
                wave_max = wp.max(wave_max, wave_c[p] * wp.sqrt(wp.exp(snow_hardening * wp.max(0.0, 1.0 - Jp[p]))))
        p += stride
    if speed_max > 0.0:
        wp.atomic_max(maxima, 0, speed_max)
    if wave_max > 0.0:
        wp.atomic_max(maxima, 1, wave_max)


class StatsReducer:
    """Owns the two small output arrays; `run` launches the reduction and reads 9 numbers back."""

    def __init__(self, device: str) -> None:
        self.device = device
        self.maxima = wp.zeros(2, dtype=float, device=device)
        self.bad = wp.zeros(N_MATERIALS, dtype=wp.int32, device=device)

    def run(self, x: wp.array, v: wp.array, F: wp.array, Jp: wp.array, material: wp.array, fixed: wp.array,
            wave_c: wp.array, snow_hardening: float, v_limit: float, max_stretch: float) -> FrameStats:
        n = x.shape[0]
        self.maxima.zero_()
        self.bad.zero_()
        threads = max(1, min(n, REDUCE_THREADS if self.device != "cpu" else 1))
        wp.launch(particle_stats, dim=threads, device=self.device,
                  inputs=[x, v, F, Jp, material, fixed, wave_c, snow_hardening, v_limit, max_stretch, n,
                          threads, self.maxima, self.bad])
        m = self.maxima.numpy()
        return FrameStats(float(m[0]), float(m[1]), self.bad.numpy().astype(np.int64))


def reference_stats(x: np.ndarray, v: np.ndarray, F: np.ndarray, Jp: np.ndarray, material: np.ndarray,
                    fixed: np.ndarray, wave_c: np.ndarray, snow_hardening: float, v_limit: float,
                    max_stretch: float) -> FrameStats:
    """The same statistics in float64 numpy from host copies (the plain reference of the kernel)."""
    v = np.asarray(v, np.float64)
    F = np.asarray(F, np.float64)
    speed = np.sqrt((v ** 2).sum(1))
    with np.errstate(all="ignore"):
        J = np.full(len(F), np.nan)
        ok = np.isfinite(F).all((1, 2))
        J[ok] = np.linalg.det(F[ok])
        norm = np.sqrt((F ** 2).sum((1, 2)))
        bad = (~np.isfinite(np.asarray(x)).all(1) | ~np.isfinite(speed) | (speed > v_limit) | ~np.isfinite(norm)
               | (norm > max_stretch) | ~(J > 1.0 / max_stretch))
    moving = ~bad & ~np.asarray(fixed, bool)
    max_speed = float(speed[moving].max()) if moving.any() else 0.0
    snow = moving & (np.asarray(material) == SNOW_ID)
    if snow.any():
        hard = np.exp(snow_hardening * np.maximum(0.0, 1.0 - np.asarray(Jp, np.float64)[snow]))
        max_wave = float((np.asarray(wave_c, np.float64)[snow] * np.sqrt(hard)).max())
    else:
        max_wave = 0.0
    counts = np.bincount(np.asarray(material)[bad], minlength=N_MATERIALS).astype(np.int64)
    return FrameStats(max_speed, max_wave, counts)
