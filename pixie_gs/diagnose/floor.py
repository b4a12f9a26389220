"""The model-error floor: how far the simulator itself is from converged for this scene.

Measured motion is the real world, not this solver at this grid. A simulation at grid spacing
dx differs from the converged answer by a smooth, systematic error — after an impact or a slide
it is easily several millimetres to centimetres — that the tracking-noise estimate (from second
time differences) cannot see. Any candidate effect can absorb part of that error, so without a
floor diagnose names "effects" that are solver error.

The floor is estimated by re-running the model as given on a finer grid (dx / REFINE) and on a
coarser one (dx · REFINE) and taking the larger RMS point distance between their predictions of
the tracked points and the baseline's: with errors e(dx·r^±1) of similar size and not aligned,
|Δ| is of the order of e(dx). (A Richardson extrapolation assuming first order would scale Δ by
r/(r−1) = 5; MPM with a fixed set of particles — one per Gaussian — does not converge
monotonically, so the plain difference is used and reported as an order-of-magnitude figure;
on the independent-engine fixtures it is within a factor of 2 of the true solver error.)

The floor enters the score's noise model: the above-noise gap is SSE − n(σ² + f²) with
f = floor/√3 per coordinate, and an effect must remove more than FLOOR_FACTOR × n f² of squared
gap (a solver error of RMS f could mimic at most n f² of it). When the gap itself is below
GAP_OVER_FLOOR × the floor, diagnose refuses to name an effect ("not converged").
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .locate import residuals, rms_gap

REFINE = 1.25           # finer grid = grid × REFINE
FLOOR_FACTOR = 2.0      # an effect must remove > FLOOR_FACTOR · n f² of squared gap
GAP_OVER_FLOOR = 2.0    # below this gap / floor ratio the gap is called solver error


@dataclass
class SolverFloor:
    """Estimated solver error of the tracked points (splat units) at the scene's grid."""

    rms: float               # RMS point distance, splat units
    grid: int                # cells along the longest side of the diagnosed scene
    dx_m: float              # its grid spacing (m)
    fine_grid: int           # the grids of the comparison runs (finer, coarser)
    coarse_grid: int
    world_scale: float       # metres per splat unit (placement)
    gap_rms: float           # the model-as-given gap, splat units
    enabled: bool = True

    @property
    def per_coordinate(self) -> float:
        return self.rms / math.sqrt(3.0)

    @property
    def converged(self) -> bool:
        """True when the gap clearly exceeds what the solver's own error could explain."""
        return (not self.enabled) or self.gap_rms > GAP_OVER_FLOOR * self.rms

    def suggested_grid(self) -> int:
        """The next grid to try: half the spacing (a first-order solver error halves)."""
        return 2 * self.grid

    def message(self) -> str:
        mm = 1000.0 * self.world_scale
        return (f"not converged at dx = {100 * self.dx_m:.3g} cm (grid {self.grid}): the residual "
                f"{mm * self.gap_rms:.3g} mm is within {GAP_OVER_FLOOR:g}× the solver-error floor "
                f"{mm * self.rms:.3g} mm (grid {self.grid} vs {self.fine_grid} and {self.coarse_grid}), so it is solver error, not a "
                f"missing effect; use --grid {self.suggested_grid()} (and more Gaussians) or more precise "
                "measurements")

    def to_dict(self) -> dict:
        return {"enabled": self.enabled, "rms": self.rms, "rms_mm": 1000.0 * self.world_scale * self.rms,
                "grid": self.grid, "fine_grid": self.fine_grid,
                "coarse_grid": self.coarse_grid, "dx_m": self.dx_m,
                "gap_rms": self.gap_rms, "gap_rms_mm": 1000.0 * self.world_scale * self.gap_rms,
                "converged": self.converged,
                "suggested_grid": None if self.converged else self.suggested_grid()}


def estimate_floor(model, scene, cloud, base_pred: np.ndarray, tracks, enabled: bool = True) -> SolverFloor:
    """Re-run the model as given at grid × REFINE and measure the change of the tracked points."""
    from ..sim.run import placement_transform

    world_scale = float(placement_transform(cloud.means, scene).scale)
    gap = rms_gap(residuals(tracks.x, base_pred, tracks.visible), tracks.visible)
    grid = int(scene.domain.grid)
    fine, coarse = int(math.ceil(grid * REFINE)), max(8, int(math.floor(grid / REFINE)))
    if not enabled:
        return SolverFloor(0.0, grid, float(scene.dx), fine, coarse, world_scale, gap, enabled=False)
    rms = 0.0
    for g in (fine, coarse):
        other = copy.deepcopy(scene)
        other.domain.grid = g
        try:
            pred = model.simulate_full(other, cloud)
        except InputError:  # the coarser grid's wall band may not fit the object
            continue
        diff = np.where(tracks.visible[:, :, None], pred - base_pred, 0.0)
        rms = max(rms, rms_gap(diff, tracks.visible))
    return SolverFloor(float(rms), grid, float(scene.dx), fine, coarse, world_scale, gap)
