"""Simulating a dense splat on a per-cell subset: choose at most N Gaussians per grid cell, run
the MPM on them, and carry every other Gaussian with its nearest simulated one.

Real captures hold 10⁵–10⁶ Gaussians, many more than the grid resolves (a 64³ grid has a few
particles per cell to work with); the run time follows the particle count, so simulating a few
per cell and carrying the rest through their neighbour's deformation gives the same motion at a
fraction of the cost. Used by `pixie simulate --per-cell`, the prepared path and the demo.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from ..errors import InputError
from ..progress import stage
from ..splat import SplatCloud
from .run import FrameState, Trajectory, placement_transform, simulate, up_rotation
from .scene import Scene


def subsample_per_cell(cloud: SplatCloud, scene: Scene, per_cell: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most `per_cell` Gaussians per simulation grid cell (chosen at random
    with `seed`), with the object placed as `scene` places it.

    Unlike a uniform random subset, this keeps thin parts (trunks, branches, can walls) as
    connected on the grid as the full splat is, while dense blobs are thinned: the particle
    count, and so the run time, follows the number of occupied cells.
    """
    if per_cell < 1:
        raise InputError(f"particles per cell must be ≥ 1, got {per_cell}")
    x = placement_transform(cloud.means, scene).to_world(cloud.means)
    cell = np.floor((x - scene.domain_origin()) / scene.dx).astype(np.int64)
    order = np.random.default_rng(seed).permutation(len(x))
    _, group = np.unique(cell[order], axis=0, return_inverse=True)
    group = group.reshape(-1)
    by_group = np.argsort(group, kind="stable")
    starts = np.concatenate([[0], np.cumsum(np.bincount(group))[:-1]])
    rank = np.empty(len(group), np.int64)
    rank[by_group] = np.arange(len(group)) - starts[group[by_group]]
    return np.sort(order[rank < per_cell])


class Carrier:
    """Moves Gaussians that were not simulated with their nearest simulated one (at frame 0),
    through its deformation: x = x0 + (x_p − x_p0) + (F_p − I)·(x0 − x_p0), Σ' = F_p Σ F_pᵀ, so
    written frames hold every Gaussian of the input while the simulation runs on a per-cell
    subset. Written as a displacement, so a Gaussian whose carrier has not moved keeps its bytes."""

    def __init__(self, all_means: np.ndarray, simulated_means: np.ndarray,
                 all_materials: np.ndarray | None = None, simulated_materials: np.ndarray | None = None) -> None:
        """With material ids, each Gaussian is carried by the nearest simulated Gaussian of its own
        material (a pot Gaussian never rides on the trunk beside it), else by the nearest one."""
        from scipy.spatial import cKDTree

        _, self.anchor = cKDTree(simulated_means).query(all_means)
        if all_materials is not None and simulated_materials is not None:
            for m in np.unique(all_materials):
                mine, theirs = all_materials == m, np.flatnonzero(simulated_materials == m)
                if len(theirs):
                    self.anchor[mine] = theirs[cKDTree(simulated_means[theirs]).query(all_means[mine])[1]]
        self.all_means = np.asarray(all_means, np.float32)
        self.anchor_start = np.asarray(simulated_means, np.float32)[self.anchor]
        self.offset = self.all_means - self.anchor_start

    def carry(self, state: FrameState) -> FrameState:
        """The FrameState of all Gaussians from that of the simulated ones (x_world: the
        carrying particle's world position)."""
        moved = state.x[self.anchor] - self.anchor_start
        if state.F is None:
            return replace(state, x=self.all_means + moved, x_world=state.x_world[self.anchor])
        F = state.F[self.anchor]
        stretch = np.einsum("nij,nj->ni", F, self.offset) - self.offset
        return replace(state, x=(self.all_means + moved + stretch).astype(np.float32),
                       x_world=state.x_world[self.anchor], F=F)


def simulate_per_cell(cloud: SplatCloud, scene: Scene, frames: int, fps: float, per_cell: int, *,
                      seed: int = 0, device: str = "auto", on_frame: Callable[[FrameState], None] | None = None,
                      fill: bool = False, positions_out: np.ndarray | None = None) -> Trajectory:
    """`simulate` on at most `per_cell` Gaussians per grid cell, the others carried (see Carrier):
    the Trajectory and every FrameState hold all Gaussians of `cloud` in file order;
    `Trajectory.simulated` says how many were simulated."""
    keep = subsample_per_cell(cloud, scene, per_cell, seed)
    # the Gaussians at the object's box faces stay too, so the subset is placed exactly as the whole
    rotated = cloud.means.astype(np.float64) @ up_rotation(scene.up).T
    keep = np.union1d(keep, np.concatenate([rotated.argmin(axis=0), rotated.argmax(axis=0)]))
    part = cloud.subset(keep)
    mid = cloud.get("material_id") if cloud.has("material_id") else None
    carrier = Carrier(cloud.means, part.means, mid, None if mid is None else mid[keep])
    stage(f"simulating {len(part)} of {len(cloud)} Gaussians (≤ {per_cell} per {scene.dx * 100:.3g} cm cell; "
          "the others move with their nearest simulated one of the same material)")
    n = len(cloud)
    if positions_out is not None and (positions_out.shape != (frames, n, 3) or positions_out.dtype != np.float32):
        raise ValueError(f"positions_out must be float32 ({frames}, {n}, 3), got {positions_out.dtype} {positions_out.shape}")
    xs = np.empty((frames, n, 3), np.float32) if positions_out is None else positions_out

    def carry(state: FrameState) -> None:
        full = carrier.carry(state)
        xs[state.index] = full.x
        if on_frame is not None:
            on_frame(full)

    traj = simulate(part, scene, frames, fps, device=device, on_frame=carry, fill=fill)
    return replace(traj, x=xs, simulated=len(part))


__all__ = ["subsample_per_cell", "Carrier", "simulate_per_cell"]
