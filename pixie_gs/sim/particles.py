"""Particles: the per-Gaussian state the MPM solver moves, in WORLD units (z-up, m, s, kg, Pa).

sim-io builds one from a SplatCloud (placement, part overrides, interior filling); the solver
only reads it at construction and hands results back through its own accessors.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import InputError
from ..materials import MATERIAL_NAMES, STATIONARY


@dataclass
class Particles:
    """N material points.

    x (N,3) m, v (N,3) m/s, volume (N,) m³, E (N,) Pa, nu (N,), density (N,) kg/m³,
    material_id (N,) int32 (pixie_gs.materials ids 0–6), yield_stress (N,) Pa
    (np.inf = no extra yield; metal with np.inf yields at scene.materials.metal_yield_strain·E,
    default 1e-3·E, typical of aluminium/steel, visco-plastic likewise; jelly with a finite
    value keeps a permanent set beyond it), fixed (N,) bool (held in place),
    part_id (N,) int32 (-1 = none), covariance optional (N,3,3) m² (the Gaussians' Σ; the
    solver only needs F, `advect_covariances` turns F into Σ').
    """

    x: np.ndarray
    v: np.ndarray
    volume: np.ndarray
    E: np.ndarray
    nu: np.ndarray
    density: np.ndarray
    material_id: np.ndarray
    yield_stress: np.ndarray = field(default=None)  # type: ignore[assignment]
    fixed: np.ndarray = field(default=None)  # type: ignore[assignment]
    part_id: np.ndarray = field(default=None)  # type: ignore[assignment]
    covariance: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(np.asarray(self.x))
        self.x = np.ascontiguousarray(self.x, dtype=np.float32).reshape(n, 3)
        self.v = np.ascontiguousarray(np.broadcast_to(np.asarray(self.v, dtype=np.float32), (n, 3)))
        self.volume = _per_particle(self.volume, n, np.float32)
        self.E = _per_particle(self.E, n, np.float32)
        self.nu = _per_particle(self.nu, n, np.float32)
        self.density = _per_particle(self.density, n, np.float32)
        self.material_id = _per_particle(self.material_id, n, np.int32)
        self.yield_stress = _per_particle(np.inf if self.yield_stress is None else self.yield_stress,
                                          n, np.float32)
        self.fixed = _per_particle(False if self.fixed is None else self.fixed, n, bool)
        self.part_id = _per_particle(-1 if self.part_id is None else self.part_id, n, np.int32)
        if self.covariance is not None:
            self.covariance = np.ascontiguousarray(self.covariance, dtype=np.float32).reshape(n, 3, 3)

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def lattice(cls, lo: tuple[float, float, float], hi: tuple[float, float, float], spacing_m: float,
                inside: Callable[[np.ndarray], np.ndarray] | None = None, **attributes: object) -> "Particles":
        """Particles on a regular lattice filling the box [lo, hi] (m), one per spacing_m³ of volume.

        `inside(x) -> mask` keeps a sub-shape (sphere, cylinder…); `attributes` are the other fields
        (E, nu, density, material_id, v…; scalars broadcast). Used by tests and benchmarks.
        """
        axes = [np.arange(a + 0.5 * spacing_m, b, spacing_m) for a, b in zip(lo, hi)]
        x = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        if inside is not None:
            x = x[inside(x)]
        attributes.setdefault("v", np.zeros(3))
        return cls(x=x, volume=spacing_m ** 3, **attributes)  # type: ignore[arg-type]

    @property
    def mass(self) -> np.ndarray:
        """Particle masses (N,) kg = density · volume."""
        return (self.density.astype(np.float64) * self.volume).astype(np.float32)

    @property
    def moving(self) -> np.ndarray:
        """Mask (N,) of particles that the solver moves (not fixed, not stationary material)."""
        return ~self.fixed & (self.material_id != STATIONARY)

    def validate(self, source: str | None = None) -> None:
        """Raise InputError (one line, naming `source`) for values the solver cannot use."""
        where = source or "particles"
        if len(self) == 0:
            raise InputError("no particles to simulate", where)
        checks = [
            (np.isfinite(self.x).all(), "non-finite positions"),
            (np.isfinite(self.v).all(), "non-finite velocities"),
            ((self.volume > 0).all() and np.isfinite(self.volume).all(), "volume must be > 0 m³"),
            ((self.E > 0).all() and np.isfinite(self.E).all(), "E must be finite and > 0 Pa"),
            (((self.nu > -1.0) & (self.nu < 0.5)).all(), "nu must lie in (-1, 0.5)"),
            ((self.density > 0).all() and np.isfinite(self.density).all(), "density must be > 0 kg/m³"),
            (np.isin(self.material_id, list(range(7))).all(), "material_id must be one of 0..6"),
            ((self.yield_stress > 0).all(), "yield_stress must be > 0 Pa (inf = none)"),
        ]
        for ok, message in checks:
            if not ok:
                raise InputError(message, where)

    def material_names(self) -> list[str]:
        """Names of the materials present, in id order (for messages)."""
        return [MATERIAL_NAMES[int(m)] for m in np.unique(self.material_id)]


def _per_particle(values: object, n: int, dtype: type) -> np.ndarray:
    """Broadcast a scalar or (N,) array to a contiguous (N,) array of `dtype`."""
    arr = np.asarray(values)
    if arr.ndim == 0:
        return np.full(n, arr, dtype=dtype)
    return np.ascontiguousarray(arr.reshape(n), dtype=dtype)
