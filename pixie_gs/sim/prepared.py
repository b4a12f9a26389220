"""Simulate a prepared capture: only its objects move, in a z-up frame, on the capture's floor.

The objects (role 0, see pixie_gs/prepare) are turned so the prepared up vector is +z, placed by
the scene as usual, and, when the capture has a floor, the scene's ground plane is put at that
floor (so the objects start where they stand in the capture). Background, ground and floater
Gaussians are held where they are: written unchanged in every frame. A closed surface shell is
filled automatically (PhysGaussian-style interior particles) unless the caller decides.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import InputError
from ..progress import stage
from ..splat import SplatCloud
from .fill import fill_interior
from .run import FrameState, Trajectory, WorldTransform, placement_transform, simulate
from .scene import Scene

SHELL_FILL_SHARE = 0.2  # interior particles ≥ this share of the object's Gaussians: a closed shell


@dataclass
class PreparedPlacement:
    """index: the simulated Gaussians (objects) in file order; rotation R (file → z-up);
    part: those Gaussians turned z-up; scene: the scene with its ground at the capture's floor;
    transform: z-up frame → world (m)."""

    index: np.ndarray
    rotation: np.ndarray
    part: SplatCloud
    scene: Scene
    transform: WorldTransform


def place_prepared(cloud: SplatCloud, prepared, scene: Scene) -> PreparedPlacement:
    """The objects of a prepared cloud turned z-up and placed; the ground at the capture's floor."""
    from ..prepare import ROLE_OBJECT

    if not cloud.has("role"):
        raise InputError("has no 'role' property; run `pixie prepare` first or pass --no-prepare", cloud.source)
    index = np.nonzero(cloud.get("role") == ROLE_OBJECT)[0]
    if len(index) == 0:
        raise InputError("preparation found no object to simulate (try --crop or --no-prepare)", cloud.source)
    R = prepared.rotation()
    part = cloud.subset(index)
    cov = part.covariances()
    part.means = (part.means.astype(np.float64) @ R.T).astype(np.float32)
    part.set_covariances(R @ cov @ R.T)
    scene = copy.deepcopy(scene)
    scene.up = "z"
    tf = placement_transform(part.means, scene)
    if prepared.ground_height is not None and scene.ground.enabled:
        floor = tf.to_world(np.array([[0.0, 0.0, prepared.ground_height]]))[0, 2]
        lowest = tf.to_world(part.means)[:, 2].min()
        scene.ground.height_m = float(min(floor, lowest))
    return PreparedPlacement(index, R, part, scene, tf)


def is_closed_shell(placed: PreparedPlacement) -> bool:
    """Whether the objects are closed surface shells (their interior would get ≥ 20 % extra particles)."""
    x = placed.transform.to_world(placed.part.means)
    filling = fill_interior(x, placed.scene.domain_origin(), placed.scene.dx, placed.scene.solver.particles_per_cell)
    return len(filling) >= SHELL_FILL_SHARE * len(x)


def simulate_prepared(cloud: SplatCloud, prepared, scene: Scene, frames: int, fps: float, device: str = "auto",
                      on_frame: Callable[[FrameState], None] | None = None, fill: bool | None = None,
                      positions_out: np.ndarray | None = None, per_cell: int | None = None) -> Trajectory:
    """Simulate the objects of a prepared, annotated `cloud`; frames hold every Gaussian in file
    coordinates (the others unchanged). `fill` None: decided by `is_closed_shell` (said).
    `per_cell`: simulate at most this many object Gaussians per grid cell and carry the others
    (see sim/subsample.py); `Trajectory.simulated` then says how many were simulated."""
    placed = place_prepared(cloud, prepared, scene)
    if fill is None:
        fill = is_closed_shell(placed)
        if fill:
            stage("the object is a closed surface shell: filling its interior (as --fill)")
    R, sel, n = placed.rotation, placed.index, len(cloud)
    x_file = cloud.means.astype(np.float32)
    x_world_static = placed.transform.to_world(cloud.means.astype(np.float64) @ R.T).astype(np.float32)
    xs = np.empty((frames, n, 3), np.float32) if positions_out is None else positions_out

    def expand(state: FrameState) -> None:
        x = x_file.copy()
        x[sel] = (state.x.astype(np.float64) @ R).astype(np.float32)
        xw = x_world_static.copy()
        xw[sel] = state.x_world
        F = None
        if state.F is not None:
            F = np.tile(np.eye(3, dtype=np.float32), (n, 1, 1))
            F[sel] = np.einsum("ji,njk,kl->nil", R, np.asarray(state.F, np.float64), R)
        xs[state.index] = x
        if on_frame is not None:
            on_frame(FrameState(state.index, state.time_s, x, xw, F))

    if per_cell is None:
        traj = simulate(placed.part, placed.scene, frames, fps, device=device, on_frame=expand, fill=fill)
    else:
        from .subsample import simulate_per_cell

        traj = simulate_per_cell(placed.part, placed.scene, frames, fps, per_cell, device=device,
                                 on_frame=expand, fill=fill)
    return Trajectory(t=traj.t, x=xs, transform=placed.transform, dt_s=traj.dt_s,
                      substeps_per_frame=traj.substeps_per_frame, filled=traj.filled, simulated=traj.simulated)
