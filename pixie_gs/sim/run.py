"""Run a simulation of an annotated splat: placement in the world, particles, frames back in the
input's coordinates. This is the API used by `pixie simulate`, `pixie diagnose` and the demo.

World frame: metres, z up (see sim/scene.py). The splat is rotated so that `scene.up` becomes
+z, scaled so its longest side is `scene.object.size_m`, and moved so its bottom centre sits at
`scene.object.position`. Everything handed back (`Trajectory.x`, `FrameState`) is mapped into
the INPUT splat's coordinates again, so frames overlay the original file.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import InputError
from ..progress import progress, stage
from ..splat import SplatCloud
from .fill import fill_interior
from .particles import Particles
from .scene import Scene


# ---------------------------------------------------------------------------------- placement
def up_rotation(up: str) -> np.ndarray:
    """Proper rotation (3,3) taking the splat axis named `up` ("y", "-z", ...) to world +z."""
    sign = -1.0 if up.startswith("-") else 1.0
    u = np.zeros(3)
    u["xyz".index(up[-1])] = sign
    z = np.array([0.0, 0.0, 1.0])
    if np.allclose(u, z):
        return np.eye(3)
    if np.allclose(u, -z):
        return np.diag([1.0, -1.0, -1.0])  # half turn about x
    k = np.cross(u, z)
    k /= np.linalg.norm(k)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + K + K @ K  # Rodrigues for a quarter turn (sin = 1, cos = 0)


@dataclass
class WorldTransform:
    """x_world = scale · R · x_input + offset (m); the inverse maps results back to the input."""

    rotation: np.ndarray  # (3,3) proper rotation
    scale: float  # metres per input unit
    offset: np.ndarray  # (3,) m

    def to_world(self, x_input: np.ndarray) -> np.ndarray:
        return np.asarray(x_input, np.float64) @ self.rotation.T * self.scale + self.offset

    def to_input(self, x_world: np.ndarray) -> np.ndarray:
        return (np.asarray(x_world, np.float64) - self.offset) @ self.rotation / self.scale

    def displacement_to_input(self, dx_world: np.ndarray) -> np.ndarray:
        """A displacement (…,3) m in world axes expressed in input units and axes."""
        return np.asarray(dx_world, np.float64) @ self.rotation / self.scale

    def deformation_to_input(self, F_world: np.ndarray) -> np.ndarray:
        """Deformation gradients (N,3,3) in input axes: Rᵀ F R (the scale cancels)."""
        R = self.rotation
        return np.einsum("ji,njk,kl->nil", R, np.asarray(F_world, np.float64), R)

    def covariance_to_world(self, cov_input: np.ndarray) -> np.ndarray:
        """Σ_world = s² R Σ_input Rᵀ (m²)."""
        R = self.rotation
        return self.scale ** 2 * np.einsum("ij,njk,lk->nil", R, np.asarray(cov_input, np.float64), R)


def placement_transform(means: np.ndarray, scene: Scene) -> WorldTransform:
    """The transform that puts the object (Gaussian centres `means`) where `scene` asks."""
    R = up_rotation(scene.up)
    rotated = np.asarray(means, np.float64) @ R.T
    lo, hi = rotated.min(axis=0), rotated.max(axis=0)
    extent = float((hi - lo).max())
    scale = scene.object.size_m / extent if extent > 0 else 1.0
    bottom_centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]) * scale
    offset = np.asarray(scene.object.position, np.float64) - bottom_centre
    return WorldTransform(R, scale, offset)


def particle_volumes(x_m: np.ndarray, origin_m: np.ndarray, dx_m: float) -> np.ndarray:
    """Volume (N,) m³ of each particle: its grid cell's volume shared among the particles in it
    (PhysGaussian's estimate, so the object's mass is ρ × the volume it occupies on the grid)."""
    idx = np.floor((np.asarray(x_m, np.float64) - origin_m) / dx_m).astype(np.int64)
    _, inverse, counts = np.unique(idx, axis=0, return_inverse=True, return_counts=True)
    return (dx_m ** 3 / counts[inverse.reshape(-1)]).astype(np.float32)


def material_arrays(cloud: SplatCloud) -> tuple[np.ndarray, ...]:
    """(material_id, E, nu, density, part_id) of the cloud, or a one-line InputError."""
    missing = [n for n in ("material_id", "E", "nu", "density") if not cloud.has(n)]
    if missing:
        raise InputError(f"has no material attributes ({', '.join(missing)} missing); "
                         "run `pixie annotate` first", cloud.source or "<splat>")
    mid, E, nu, rho = cloud.get_materials()
    part = cloud.get("part_id").astype(np.int32) if cloud.has("part_id") else np.full(len(cloud), -1, np.int32)
    return mid, E, nu, rho, part


def build_particles(cloud: SplatCloud, scene: Scene, fill: bool = False) -> tuple[Particles, WorldTransform]:
    """Particles in world units for `cloud` placed by `scene`: the first len(cloud) are the
    Gaussians in file order, followed by interior filling particles when `fill` is set.

    Material attributes come from the file (E Pa, ν, ρ kg/m³, material_id, optional part_id);
    `scene.part_overrides` scale E/ρ, set yield stresses and fix parts; `scene.fixed` holds
    particles by part id and/or by region (world m, tested at the start).
    """
    mid, E, nu, rho, part = material_arrays(cloud)
    tf = placement_transform(cloud.means, scene)
    x = tf.to_world(cloud.means)
    origin, dx = scene.domain_origin(), scene.dx
    if fill:
        filling = fill_interior(x, origin, dx, scene.solver.particles_per_cell)
        if len(filling):
            src = filling.source_index
            x = np.concatenate([x, filling.x.astype(np.float64)])
            mid, E, nu, rho, part = (np.concatenate([a, a[src]]) for a in (mid, E, nu, rho, part))
    _check_inside_domain(x, scene, cloud.source)
    E = E.astype(np.float32).copy()
    rho = rho.astype(np.float32).copy()
    yield_stress = np.full(len(x), np.inf, np.float32)
    fixed = np.zeros(len(x), bool)
    for part_id, override in scene.part_overrides.items():
        sel = part == part_id
        E[sel] *= np.float32(override.E_scale)
        rho[sel] *= np.float32(override.density_scale)
        if override.yield_stress_pa is not None:
            yield_stress[sel] = override.yield_stress_pa
        if override.fixed:
            fixed |= sel
    for spec in scene.fixed:
        if spec.part_ids:
            fixed |= np.isin(part, spec.part_ids)
        if spec.region is not None:
            fixed |= spec.region.contains(x)
    particles = Particles(x=x.astype(np.float32), v=np.zeros(3, np.float32),
                          volume=particle_volumes(x, origin, dx), E=E, nu=nu, density=rho,
                          material_id=mid, yield_stress=yield_stress, fixed=fixed, part_id=part)
    particles.validate(cloud.source)
    return particles, tf


def _check_inside_domain(x_m: np.ndarray, scene: Scene, source: str | None) -> None:
    """InputError when the placed object does not fit inside the simulation box."""
    # the solver's limits: at least one grid node of B-spline support on every side
    origin = scene.domain_origin()
    lo, hi = origin + scene.dx, origin + (np.asarray(scene.grid_dims) - 2.0) * scene.dx
    if (x_m.min(axis=0) < lo - 1e-9).any() or (x_m.max(axis=0) > hi + 1e-9).any():
        raise InputError(
            f"the placed object spans {np.round(x_m.min(axis=0), 3).tolist()}..{np.round(x_m.max(axis=0), 3).tolist()} m, "
            f"outside the simulation domain {np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} m; "
            "enlarge domain.size_m or shrink object.size_m in the scene", source or "scene")


_material_arrays = material_arrays  # earlier private name, used by cmd_diagnose


# ---------------------------------------------------------------------------------- running
@dataclass
class FrameState:
    """One output frame: index, time (s), positions (N,3) in input coordinates, positions (N,3)
    in world metres, and deformation gradients F (N,3,3) in input axes (None at frame 0 = I)."""

    index: int
    time_s: float
    x: np.ndarray
    x_world: np.ndarray
    F: np.ndarray | None


@dataclass
class Trajectory:
    """t (T,) s; x (T,N,3) Gaussian centres in the input splat's coordinates (filling particles
    excluded); F (T,N,3,3) in input axes only when asked for (`keep_deformation`)."""

    t: np.ndarray
    x: np.ndarray
    transform: WorldTransform
    F: np.ndarray | None = None
    dt_s: float = float("nan")  # stable substep of the elastic CFL (s)
    substeps_per_frame: int = 0  # substeps the last frame took
    filled: int = 0  # interior particles simulated but not output
    simulated: int | None = None  # Gaussians simulated when the others were carried (sim/subsample.py)

    def __len__(self) -> int:
        return len(self.t)


def simulate(
    cloud: SplatCloud,
    scene: Scene,
    frames: int,
    fps: float,
    device: str = "auto",
    on_frame: Callable[[FrameState], None] | None = None,
    fill: bool = False,
    keep_deformation: bool = False,
    quiet: bool = False,
    positions_out: np.ndarray | None = None,
) -> Trajectory:
    """Simulate `cloud` in `scene` for `frames` output frames (frame 0 is the initial state at
    t = 0, frame i at t = i / fps s). `on_frame` is called with each FrameState as soon as it
    is ready (used to stream frames to disk and rerun). `keep_deformation` stores F per frame in
    the Trajectory (T·N·36 bytes); `quiet` drops the stage line and progress bar (for callers
    that simulate in loops); `positions_out` (frames, N, 3) float32, e.g. a memory-mapped file,
    receives the trajectory instead of a new in-memory array (so memory stays flat however many
    frames). Raises InputError for unusable input, ComputationError on divergence."""
    from ..devices import resolve_warp_device
    from .solver import MPMSolver

    if frames < 1:
        raise InputError(f"frames must be ≥ 1, got {frames}")
    if not fps > 0:
        raise InputError(f"fps must be > 0, got {fps}")
    particles, tf = build_particles(cloud, scene, fill=fill)
    n = len(cloud)
    solver = MPMSolver(particles, scene, resolve_warp_device(device))
    if not quiet:
        describe_placement(cloud, scene, particles, solver.dt)
    x0_in = cloud.means.astype(np.float32)
    x0_world = particles.x[:n].astype(np.float64)
    t = np.arange(frames, dtype=np.float64) / fps
    if positions_out is not None and (positions_out.shape != (frames, n, 3) or positions_out.dtype != np.float32):
        raise ValueError(f"positions_out must be float32 ({frames}, {n}, 3), got {positions_out.dtype} {positions_out.shape}")
    xs = np.empty((frames, n, 3), np.float32) if positions_out is None else positions_out
    xs[0] = x0_in
    Fs = np.empty((frames, n, 3, 3), np.float32) if keep_deformation else None
    if Fs is not None:
        Fs[0] = np.eye(3, dtype=np.float32)
    if on_frame is not None:
        on_frame(FrameState(0, 0.0, xs[0], x0_world.astype(np.float32), None))
    need_F = keep_deformation or on_frame is not None
    steps = range(1, frames) if quiet else progress(range(1, frames), desc="simulate", total=frames - 1, unit="frame")
    for i in steps:
        solver.step_frame(1.0 / fps)
        xw = np.asarray(solver.positions())[:n]
        xs[i] = x0_in + tf.displacement_to_input(xw - x0_world).astype(np.float32)
        F = tf.deformation_to_input(np.asarray(solver.deformation_gradients())[:n]) if need_F else None
        if Fs is not None:
            Fs[i] = F
        if on_frame is not None:
            on_frame(FrameState(i, float(t[i]), xs[i], xw.astype(np.float32), F))
    return Trajectory(t=t, x=xs, transform=tf, F=Fs, dt_s=float(solver.dt),
                      substeps_per_frame=int(solver.substeps_last_frame), filled=len(particles) - n)


def describe_placement(cloud: SplatCloud, scene: Scene, particles: Particles, dt_s: float) -> None:
    """One stage line: where the object went, how many particles it became, the substep."""
    lo = particles.x.min(axis=0).astype(np.float64)
    hi = particles.x.max(axis=0).astype(np.float64)
    filled = len(particles) - len(cloud)
    stage(f"placed {len(cloud)} Gaussians{f' (+{filled} interior particles)' if filled else ''} as a "
          f"{scene.object.size_m:g} m object (up={scene.up}) at {np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} m; "
          f"grid {scene.dx * 100:.3g} cm, substep {dt_s:.3g} s")


__all__ = ["WorldTransform", "FrameState", "Trajectory", "build_particles", "simulate", "placement_transform",
           "material_arrays",
           "particle_volumes", "up_rotation"]
