"""MPMSolver: moves Particles through a Scene with MLS-MPM in NVIDIA Warp ("cpu" or "cuda").

The substep dt comes from a CFL bound on the fastest elastic (P-)wave of the particles that move,
c = √(E(1−ν)/(ρ(1+ν)(1−2ν))), and on the fastest particle; each frame is split into
ceil(frame_dt / dt) substeps. After every frame a guard checks that velocities and deformation
gradients are finite and bounded, and raises ComputationError naming the frame and material.

No particle array leaves the device inside a frame: the CFL inputs (fastest particle, hardened
snow) and the guard are reductions on the device (sim/reduce.py) that read back 9 numbers.
The particle arrays are kept in grid-cell order (sim/sort.py), re-sorted every `sort_every`
frames; `order` maps array slots to the caller's particle indices and every accessor
(positions(), velocities(), ...) answers in the caller's order.
"""
from __future__ import annotations

import math
import time

import numpy as np
import warp as wp

# no init banner / per-module load lines on stdout (warp ≥ 1.10 uses log_level, not config.quiet)
wp.config.log_level = wp.LOG_WARNING

from ..devices import resolve_warp_device  # noqa: E402
from ..errors import ComputationError, InputError
from ..materials import MATERIAL_NAMES, METAL, SNOW, STATIONARY, VISCOPLASTIC
from ..progress import stage
from . import kernels, p2g_column
from .constitutive import NO_YIELD
from .particles import Particles
from .reduce import FrameStats, StatsReducer, reference_stats
from .scene import BOUNDARY_CELLS, Scene
from .rigid import PartChoice, RigidBodies, plan_stiff_parts, true_stiffness_report, wall_bounds
from .sort import cell_order, cell_runs, chunk_runs, permute_in_place
from .state import ARRAY_FIELDS, State

CHUNK = 8  # particles per P2G thread while the particles are in no cell order (sort_every = 0)
SORT_SUBSTEPS = 4  # with sorting on, the run-based P2Gs' cell order is refreshed every this many substeps
RESORT_SUBSTEP = 16  # resort_inside: the frame's array re-sort goes in at the first index sort from this substep
COLUMN_RUN = 32  # p2g="column"/"slab": particles per run at most (a run is one column of cells along z)
# P2G kernels; the column ones (sim/p2g_column.py): kernel, its carry twin, threads per run
COLUMN_KINDS = {"column": (p2g_column.p2g_column, p2g_column.p2g_column_carry, p2g_column.COLUMN_THREADS),
                "slab": (p2g_column.p2g_slab, p2g_column.p2g_slab_carry, p2g_column.SLAB_THREADS)}
P2G_KINDS = ("auto", "chunked", "atomic", *COLUMN_KINDS)
# p2g="auto" on a GPU with sorting on: the fastest measured configuration (H100, docs/benchmarks.md
# issue 14: 1.23x / 1.43x the chunked P2G at 1M / 4M particles): the column P2G, affine matrices
# carried from G2P, P2G blocks of 128 threads (96 registers per thread: 20 resident warps per SM)
GPU_P2G, GPU_CARRY_AFFINE, GPU_P2G_BLOCK_DIM = "column", True, 128
SORT_MIN_PARTICLES = 50_000  # on a GPU, smaller runs fit in cache and are launch-bound: no sorting

FAR = 1.0e30  # "unbounded" for regions and time windows passed to kernels
MAX_STRETCH = 1.0e3  # ‖F‖ or 1/J beyond this counts as diverged


def p_wave_speed(E_pa: np.ndarray, nu: np.ndarray, density: np.ndarray) -> np.ndarray:
    """Elastic P-wave speed (m/s) √(E(1−ν)/(ρ(1+ν)(1−2ν))) per particle."""
    E, nu, rho = (np.asarray(a, dtype=np.float64) for a in (E_pa, nu, density))
    return np.sqrt(E * (1.0 - nu) / (rho * (1.0 + nu) * (1.0 - 2.0 * nu)))


def lame_parameters(E_pa: np.ndarray, nu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(μ, λ) in Pa from Young's modulus and Poisson ratio."""
    E, nu = np.asarray(E_pa, dtype=np.float64), np.asarray(nu, dtype=np.float64)
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


def p2g_choice(p2g: str, device: str, sort_every: int, carry_affine: bool | None = None,
               block_dim: int | None = None) -> tuple[str, bool, int | None]:
    """(P2G kind, carry_affine, P2G block size or None for Warp's 256) that MPMSolver runs for its
    options `p2g`, `carry_affine`, `p2g_block_dim` on `device` with `sort_every`: "auto" is GPU_P2G
    with GPU_CARRY_AFFINE and GPU_P2G_BLOCK_DIM (each unless given) on a GPU that sorts, else
    "atomic"; a kind named is run with the options given (None: off, 256). ValueError for
    choices that cannot run."""
    if p2g not in P2G_KINDS:
        raise ValueError(f"p2g must be one of {', '.join(P2G_KINDS)}, got {p2g!r}")
    if p2g in COLUMN_KINDS and sort_every == 0:
        raise ValueError(f"p2g={p2g!r} needs the particles in cell order (sort_every > 0)")
    auto_gpu = p2g == "auto" and device != "cpu" and sort_every > 0
    if p2g == "auto":
        p2g = GPU_P2G if auto_gpu else "atomic"
    if carry_affine is None:
        carry_affine = GPU_CARRY_AFFINE and auto_gpu
    if carry_affine and p2g not in COLUMN_KINDS:
        raise ValueError(f"carry_affine needs p2g 'column' or 'slab', got {p2g!r}")
    if block_dim is None and auto_gpu:
        block_dim = GPU_P2G_BLOCK_DIM
    return p2g, bool(carry_affine), None if block_dim is None else int(block_dim)


def held_particles(particles: Particles, scene: Scene) -> np.ndarray:
    """Mask (N,) of particles held in place: fixed, stationary material, or named by scene.fixed."""
    fixed = particles.fixed | (particles.material_id == STATIONARY)
    for spec in scene.fixed:
        if spec.region is not None:
            fixed |= spec.region.contains(particles.x)
        if spec.part_ids:
            fixed |= np.isin(particles.part_id, spec.part_ids)
    return fixed


def yield_stresses(particles: Particles, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(yield stress (N,) Pa the kernels use — NO_YIELD for none —, mask of those set from the
    scene's default yield strain × E for metal and visco-plastic particles without their own)."""
    ys = particles.yield_stress.astype(np.float64).copy()
    from_strain = np.zeros(len(ys), bool)
    mats = scene.materials
    E = particles.E.astype(np.float64)
    for mid, strain in ((METAL, mats.metal_yield_strain), (VISCOPLASTIC, mats.viscoplastic_yield_strain)):
        default = (particles.material_id == mid) & ~np.isfinite(ys)
        ys[default] = strain * E[default]
        from_strain |= default
    ys[~np.isfinite(ys)] = NO_YIELD
    return ys, from_strain


class MPMSolver:
    """MLS-MPM/APIC solver. World units: m, s, kg, Pa; z up.

    Attributes: time_s (simulated time), frame (frames done), dt (current stable substep, s),
    substeps_last_frame, particle_substeps (total particles × substeps, for throughput figures),
    stiffness_scale (≤ 1: factor applied to the stiffest parts' E to respect
    scene.solver.max_substeps_per_frame; 1 when nothing was softened), timing (host seconds
    of the last frame: stats, launch, guard, sort; the guard's figure includes waiting for the
    device to finish the frame), kernel_timer (None, or an object whose mark(name) is called
    after each kernel launch: benchmarks time kernels with it).
    The scene is read once, at construction; build a new solver to change it.
    `sort_every`: re-sort the particle arrays into cell order every this many frames (0: keep
    the caller's order, never sort; None: every frame, except on a GPU below SORT_MIN_PARTICLES);
    inside a frame the chunked and column P2Gs get a fresh cell order (an index, the arrays stay
    put) every `sort_substeps` substeps (None: SORT_SUBSTEPS). Sorted and unsorted runs agree to
    float rounding. `resort_inside`: with the chunked or column P2G, a frame's
    re-sort of the arrays replaces its first in-frame index sort from substep RESORT_SUBSTEP on,
    instead of running at the frame start, where the device waits while the host issues it.
    `g2p_max_registers`: compile G2P with at most this many registers per CUDA thread
    (kernels.register_capped; None: the compiler's choice).
    The Warp arrays (x, v, F, ...) are in slot order; use the accessors for the caller's order.
    `p2g`: "chunked" (one thread per run of same-cell particles sums them before touching the
    grid, kernels.p2g_chunked), "atomic" (one global atomic per particle and node, kernels.p2g, the
    plain reference), "column" (nine threads per run of up to `column_run` particles of one column
    of cells, each sliding a 3-node window along z, into a packed vec4 grid: sim/p2g_column.py;
    needs sorting), "slab" (the same with three threads per run, 3×3-node windows) or "auto":
    on a GPU when sorting, GPU_P2G (column) with carry_affine and p2g_block_dim GPU_P2G_BLOCK_DIM
    (128) unless those are given; else (the CPU, where atomic measured fastest, or a GPU without
    sorting) atomic. The chosen values are in p2g_kind, carry_affine, p2g_block_dim.
    `vector_atomics` (column, slab): a node's momentum and mass go out as one 16-byte
    atomic on sm_90+ (False: four scalar atomics). `p2g_max_registers`: compile the P2G kernel
    with at most this many registers per CUDA thread (None: the compiler's choice).
    `carry_affine` (column, slab): inside a frame each G2P but the last stores the next P2G's
    affine matrix (p2g_column.g2p_carry) in place of C and τ, which the last one stores as usual;
    never while rigid bodies are present (they overwrite C and τ after G2P: `carrying` says
    whether frames carry now). None: on where "auto" chose the column P2G, else off.
    `p2g_block_dim`: CUDA threads per block of the P2G launch (None: GPU_P2G_BLOCK_DIM where "auto"
    chose the column P2G, else Warp's 256; at 96 registers per thread, blocks of 128 let 20 warps
    per SM stay resident instead of 16).
    """

    def __init__(self, particles: Particles, scene: Scene, device: str = "cpu", sort_every: int | None = None,
                 p2g: str = "auto", sort_substeps: int | None = None, resort_inside: bool = False,
                 g2p_max_registers: int | None = None, column_run: int | None = None, vector_atomics: bool = True,
                 p2g_max_registers: int | None = None, carry_affine: bool | None = None,
                 p2g_block_dim: int | None = None) -> None:
        particles.validate()
        self.scene = scene
        self.device = resolve_warp_device(device)
        self.n = len(particles)
        self.time_s = 0.0
        self.frame = 0
        self.substeps_last_frame = 0
        self.particle_substeps = 0
        self.stiffness_scale = 1.0
        self.stiff_part_choices: list[PartChoice] = []  # per part over the substep budget (sim/rigid.py)
        self.rigid: RigidBodies | None = None  # parts too stiff for the budget, run as rigid bodies
        self._part_id = particles.part_id.copy()
        self._true_reported = False  # stiff_parts "true": the per-part budget lines were printed
        self._mass_host = particles.mass  # kg, for rigid bodies
        if sort_every is None:
            sort_every = 1 if self.device == "cpu" or self.n >= SORT_MIN_PARTICLES else 0
        self.sort_every = int(sort_every)
        p2g, carry_affine, p2g_block_dim = p2g_choice(p2g, self.device, self.sort_every, carry_affine, p2g_block_dim)
        self.p2g_kind = p2g
        self.sort_substeps = SORT_SUBSTEPS if sort_substeps is None else int(sort_substeps)
        if self.sort_substeps < 1:
            raise ValueError(f"sort_substeps must be >= 1, got {sort_substeps!r}")
        self.resort_inside = bool(resort_inside)
        self.g2p_max_registers = g2p_max_registers
        self.p2g_max_registers = p2g_max_registers
        self.column_run = COLUMN_RUN if column_run is None else int(column_run)
        if self.column_run < 1:
            raise ValueError(f"column_run must be >= 1, got {column_run!r}")
        self.vector_atomics = bool(vector_atomics)
        self.carry_affine = carry_affine
        self.p2g_block_dim = p2g_block_dim
        self._packed = p2g in COLUMN_KINDS  # grid_mv (momentum xyz, mass per node) instead of two arrays
        self._runs_p2g = p2g == "chunked" or self._packed  # P2G threads take runs from the cell sort
        self.timing: dict[str, float] = {}
        self.kernel_timer = None
        self._impulse_done = [False] * len(scene.impulses)

        self.dx = scene.dx
        self.dims = scene.grid_dims
        self.origin = scene.domain_origin()
        self._check_inside(particles.x)

        self.material_id = particles.material_id.copy()
        fixed = held_particles(particles, scene)
        self.fixed = fixed
        self._E = particles.E.astype(np.float64)
        self._nu = particles.nu.astype(np.float64)
        self._wave_speed = p_wave_speed(particles.E, particles.nu, particles.density)
        self._moving = ~fixed
        self._moving_snow = self._moving & (self.material_id == SNOW)  # hardening changes their CFL

        ys, self._yield_from_strain = yield_stresses(particles, scene)  # from strain: scaled with a cap
        self._yield_base = ys.copy()

        d = self.device
        v0 = np.where(fixed[:, None], 0.0, particles.v).astype(np.float32)
        self.state = State.at_rest(particles.x, v0, d)  # x, v, C, F, stress (τ, Pa), Jp: sim/state.py
        self.volume = wp.array(particles.volume, dtype=float, device=d)
        self.mass = wp.array(particles.mass, dtype=float, device=d)
        self.mu = wp.zeros(self.n, dtype=float, device=d)
        self.lam = wp.zeros(self.n, dtype=float, device=d)
        self.wave_c = wp.zeros(self.n, dtype=float, device=d)  # P-wave speed (m/s) at the current stiffness
        self._set_stiffness(np.ones(self.n))
        self.yield_stress = wp.array(ys.astype(np.float32), dtype=float, device=d)
        self.material = wp.array(self.material_id, dtype=wp.int32, device=d)
        self.fixed_flag = wp.array(fixed.astype(np.int32), dtype=wp.int32, device=d)
        self.order = wp.array(np.arange(self.n, dtype=np.int32), dtype=wp.int32, device=d)  # slot → index
        self.run_start = wp.zeros(self.n + 1, dtype=wp.int32, device=d)  # P2G thread t: run_start[t] ≤ p < [t+1]
        self.run_count = wp.zeros(1, dtype=wp.int32, device=d)  # runs in run_start (stays on the device)
        self.run_key = wp.zeros(self.n if self._packed else 1, dtype=wp.int32, device=d)  # column: first cell per run
        chunk_runs(self.n, CHUNK, self.run_start, self.run_count)
        self._identity = wp.array(np.arange(self.n, dtype=np.int32), dtype=wp.int32, device=d)
        self._p2g_index = self._identity  # P2G reads particle index[i] for run position i
        self._order_host: np.ndarray | None = None  # host copy of `order`, None when stale
        self._reducer = StatsReducer(d)

        self.grid_mass = wp.zeros(self.dims, dtype=float, device=d)
        # packed: P2G sums into grid_mv; grid_mass only takes the node masses for rigid coupling
        self.grid_momentum = None if self._packed else wp.zeros(self.dims, dtype=wp.vec3, device=d)
        self.grid_mv = wp.zeros(self.dims, dtype=wp.vec4, device=d) if self._packed else None
        self.grid_fixed = wp.zeros(self.dims, dtype=float, device=d)
        self.grid_velocity = wp.zeros(self.dims, dtype=wp.vec3, device=d)

        self.grid_info = kernels.GridInfo()
        self.grid_info.origin = wp.vec3(*self.origin)
        self.grid_info.dx = self.dx
        self.grid_info.inv_dx = 1.0 / self.dx
        self.grid_info.dims = wp.vec3i(*self.dims)
        self.material_params = self._material_params()
        self._upload_wind()
        self._record_launches()
        if self.sort_every > 0:
            self._resort()

    # ------------------------------------------------------------------ state (sim/state.py)
    x = property(lambda self: self.state.x, lambda self, a: setattr(self.state, "x", a))
    v = property(lambda self: self.state.v, lambda self, a: setattr(self.state, "v", a))
    C = property(lambda self: self.state.C, lambda self, a: setattr(self.state, "C", a))
    F = property(lambda self: self.state.F, lambda self, a: setattr(self.state, "F", a))
    stress = property(lambda self: self.state.stress, lambda self, a: setattr(self.state, "stress", a))
    Jp = property(lambda self: self.state.Jp, lambda self, a: setattr(self.state, "Jp", a))

    def new_state(self) -> State:
        """A copy of the solver's own state (slot order, same time) for step() to advance."""
        out = self.state.clone()
        out.time_s = self.time_s
        return out

    def step(self, state_in: State, state_out: State, dt: float) -> None:
        """One substep of `dt` s from `state_in` to `state_out` (the same object: in place).

        Both states are in this solver's slot order (make them with new_state()); the solver's
        own state and clock are untouched. Impulses with time_s in [state_in.time_s,
        state_in.time_s + dt) are applied first; state_out.time_s = state_in.time_s + dt.
        No CFL choice and no guard here: that is step_frame's job (dt is the caller's)."""
        if len(state_in) != self.n or len(state_out) != self.n:
            raise ValueError(f"states must hold this solver's {self.n} particles")
        if state_out is not state_in:
            state_out.assign(state_in)
        t = state_in.time_s
        own = self.state
        self.state = state_out
        self._bind_state()
        try:
            for imp in self.scene.impulses:
                if t <= imp.time_s < t + dt:
                    self._launch_impulse(imp)
            self._substep(dt, t)
        finally:
            self.state = own
            self._bind_state()
        state_out.time_s = t + dt

    def _bind_state(self) -> None:
        """Point the recorded P2G and G2P launches at self.state's arrays."""
        for launch in (self._p2g, self._p2g_carry, self._g2p, self._g2p_carry):
            if launch is None:
                continue
            takes = {arg.label for arg in launch.kernel.adj.args}
            for name in ARRAY_FIELDS:
                if name in takes:
                    launch.set_param_by_name(name, getattr(self.state, name))

    # ------------------------------------------------------------------ set-up helpers
    def _check_inside(self, x: np.ndarray) -> None:
        g = (x - self.origin) / self.dx
        hi = np.asarray(self.dims) - 2.0
        outside = np.any((g < 1.0) | (g > hi), axis=1)
        if outside.any():
            top = self.origin + hi * self.dx
            raise InputError(
                f"{int(outside.sum())} of {self.n} particles lie outside the simulation domain "
                f"[{np.round(self.origin + self.dx, 3).tolist()}, {np.round(top, 3).tolist()}] m; "
                "enlarge domain.size_m or move object.position / domain.origin", "scene")

    def _material_params(self) -> kernels.MaterialParams:
        m = self.scene.materials
        mp = kernels.MaterialParams()
        s = math.sin(math.radians(m.sand_friction_angle_deg))
        mp.sand_alpha = math.sqrt(2.0 / 3.0) * 2.0 * s / (3.0 - s)
        mp.snow_theta_c = m.snow_critical_compression
        mp.snow_theta_s = m.snow_critical_stretch
        mp.snow_hardening = m.snow_hardening
        mp.viscoplastic_viscosity = m.viscoplastic_viscosity_pa_s
        mp.fluid_viscosity = m.fluid_viscosity_pa_s
        return mp

    def _upload_wind(self) -> None:
        winds = self.scene.wind
        acc = np.zeros((max(len(winds), 1), 3), np.float32)
        lo = np.full_like(acc, -FAR)
        hi = np.full_like(acc, FAR)
        timing = np.zeros((len(acc), 4), np.float32)
        for i, w in enumerate(winds):
            acc[i] = w.acceleration
            if w.region is not None:
                lo[i], hi[i] = w.region.min, w.region.max
            timing[i] = (w.start_s, FAR if w.end_s is None else w.end_s, w.gust_amplitude, w.gust_frequency_hz)
        d = self.device
        self.wind_acc = wp.array(acc, dtype=wp.vec3, device=d)
        self.wind_lo = wp.array(lo, dtype=wp.vec3, device=d)
        self.wind_hi = wp.array(hi, dtype=wp.vec3, device=d)
        self.wind_timing = wp.array(timing, dtype=wp.vec4, device=d)
        self._wind_peak = sum(float(np.linalg.norm(w.acceleration)) * (1.0 + w.gust_amplitude) for w in winds)

    def _set_stiffness(self, scale: np.ndarray) -> None:
        """Upload μ, λ and the wave speed for E·scale (scale < 1 only where stiffness had to be
        capped); `scale` is in the caller's particle order."""
        mu, lam = lame_parameters(self._E * scale, self._nu)
        c = self._wave_speed * np.sqrt(scale)
        self.mu.assign(self._to_slots(mu.astype(np.float32)))
        self.lam.assign(self._to_slots(lam.astype(np.float32)))
        self.wave_c.assign(self._to_slots(c.astype(np.float32)))
        static = self._moving & ~self._moving_snow  # their wave speed never changes
        self._c_static = float(c[static].max()) if static.any() else 0.0
        self._scale = scale

    # ------------------------------------------------------------------ particle order
    def _slot_order(self) -> np.ndarray | None:
        """order (slot → caller index) on the host, None while it is the identity."""
        if self._order_host is None:
            self._order_host = self.order.numpy().copy()
        return self._order_host

    def _to_slots(self, a: np.ndarray) -> np.ndarray:
        """A per-particle host array in the caller's order, rearranged into slot order."""
        return a if not hasattr(self, "order") else a[self._slot_order()]

    def _to_caller(self, a: np.ndarray) -> np.ndarray:
        """A per-particle array in slot order, rearranged into the caller's order (a copy)."""
        out = np.empty_like(a)
        out[self._slot_order()] = a
        return out

    def _particle_arrays(self) -> list[wp.array]:
        return [self.x, self.v, self.C, self.stress, self.F, self.volume, self.mass, self.mu, self.lam,
                self.wave_c, self.yield_stress, self.material, self.Jp, self.fixed_flag, self.order]

    def _resort(self) -> None:
        """Put the particle arrays into grid-cell order (on the device; order follows)."""
        perm, keys = cell_order(self.x, self.grid_info)
        permute_in_place(perm, self._particle_arrays())
        self._order_host = None
        self._cell_runs(keys)
        self._set_p2g_index(self._identity)

    def _reindex(self) -> None:
        """A fresh cell order for the run-based P2Gs only: sort an index, not the arrays (cheap, all
        on the device: done every sort_substeps substeps as particles drift between cells)."""
        perm, keys = cell_order(self.x, self.grid_info)
        self._cell_runs(keys)
        self._set_p2g_index(perm)

    def _cell_runs(self, keys: wp.array) -> None:
        """The P2G runs of cell-sorted `keys`: one cell each, or (column) one column of cells."""
        if self._packed:
            cell_runs(keys, self.run_start, self.run_count, self.column_run, column=self.dims[2],
                      run_keys=self.run_key)
        else:
            cell_runs(keys, self.run_start, self.run_count)

    def _set_p2g_index(self, index: wp.array) -> None:
        self._p2g_index = index
        for launch in (self._p2g, self._p2g_carry) if self._runs_p2g else ():
            if launch is not None:
                launch.set_param_by_name("index", index)

    @property
    def n_runs(self) -> int:
        """Number of P2G particle runs (cells) since the last sort (reads the device)."""
        return int(self.run_count.numpy()[0])

    # ------------------------------------------------------------------ time stepping
    def frame_stats(self, v_limit_mps: float = FAR) -> FrameStats:
        """Device reduction of the current state: fastest moving particle, fastest hardened snow
        wave, guard failures per material (speed above `v_limit_mps` counts as a failure)."""
        return self._reducer.run(self.x, self.v, self.F, self.Jp, self.material, self.fixed_flag, self.wave_c,
                                 self.scene.materials.snow_hardening, v_limit_mps, MAX_STRETCH)

    def reference_frame_stats(self, v_limit_mps: float = FAR) -> FrameStats:
        """frame_stats computed in numpy from host copies of the particle arrays (the plain
        reference the device reduction is tested against; slow: copies the whole state)."""
        return reference_stats(self.x.numpy(), self.v.numpy(), self.F.numpy(), self.Jp.numpy(),
                               self.material.numpy(), self.fixed_flag.numpy(), self.wave_c.numpy(),
                               self.scene.materials.snow_hardening, v_limit_mps, MAX_STRETCH)

    def _max_wave_speed(self, stats: FrameStats | None) -> float:
        if self._moving_snow.any():
            stats = stats or self.frame_stats()
            return max(self._c_static, stats.max_snow_wave_mps)
        return self._c_static

    @property
    def max_wave_speed(self) -> float:
        """Fastest elastic wave (m/s) among moving particles, after any stiffness cap and with
        snow's current hardening (E·exp(ξ(1 − Jp)): compacted snow stiffens and needs smaller dt)."""
        return self._max_wave_speed(None)

    def _cfl_dt(self, c_mps: float) -> float:
        return math.inf if c_mps == 0.0 else self.scene.solver.cfl * self.dx / c_mps

    @property
    def dt(self) -> float:
        """Largest stable substep (s) from the elastic-wave CFL: cfl · dx / c_max."""
        return self._cfl_dt(self.max_wave_speed)

    def substeps_for(self, frame_dt_s: float, stats: FrameStats | None = None) -> int:
        """Substeps this frame needs: elastic CFL and velocity CFL, within max_substeps_per_frame.
        `stats`: this state's frame_stats when the caller has them (else one reduction runs)."""
        s = self.scene.solver
        stats = stats or self.frame_stats()
        dt = self._cfl_dt(self._max_wave_speed(stats))
        n_elastic = math.ceil(frame_dt_s / dt) if math.isfinite(dt) else 1
        if n_elastic > s.max_substeps_per_frame:
            self._cap_stiffness(frame_dt_s)
            n_elastic = math.ceil(frame_dt_s / self.dt)
        elif s.stiff_parts == "true" and not self._true_reported:  # report the budget each part uses
            self._true_reported = True
            for choice in true_stiffness_report(self._part_id, self.material_id, self._E, self._wave_speed,
                                                self._moving, frame_dt_s, s.cfl, self.dx, s.max_substeps_per_frame):
                stage(choice.line())
                self.stiff_part_choices.append(choice)
        v_bound = self._speed_bound(frame_dt_s, stats.max_speed_mps)
        n_velocity = math.ceil(frame_dt_s * v_bound / (s.velocity_cfl * self.dx))
        return int(min(max(1, n_elastic, n_velocity), s.max_substeps_per_frame))

    def _speed_bound(self, frame_dt_s: float, v_now: float) -> float:
        """Upper estimate (m/s) of particle speed during the next frame, from the fastest moving
        particle now (`v_now`, m/s), the accelerations and the impulses still to come."""
        accel = float(np.linalg.norm(self.scene.gravity)) + self._wind_peak
        kicks = sum(float(np.linalg.norm(imp.velocity_change))
                    for imp, done in zip(self.scene.impulses, self._impulse_done)
                    if not done and imp.time_s < self.time_s + frame_dt_s)
        return v_now + accel * frame_dt_s + kicks

    def _cap_stiffness(self, frame_dt_s: float) -> None:
        """Parts whose wave speed needs more substeps than the budget: per part a rigid body coupled
        to the grid, softened, or an InputError, by scene.solver.stiff_parts (sim/rigid.py); one
        printed line per part."""
        s = self.scene.solver
        plan = plan_stiff_parts(s.stiff_parts, self.positions(), self._part_id, self.material_id, self._E,
                                self._wave_speed, self._scale, self._moving, self.fixed, frame_dt_s, s.cfl, self.dx,
                                s.max_substeps_per_frame, self.origin, allow_rigid=self.rigid is None)
        for choice in plan.choices:
            stage(choice.line())
        self.stiff_part_choices.extend(plan.choices)
        scale = plan.E_scale
        if plan.held.any():
            self._hold(plan.held)
        if plan.n_bodies:
            sc = self.scene
            self.rigid = RigidBodies(plan.body, self.positions(), self.velocities(), self._mass_host, self.dims,
                                     sc.gravity, sc.damping, self.device)
            self.rigid.place(self.x, self.v, self.C, self.F, self.stress, self.order)
            # rigid particles are not scattered: the grid carries the soft material only
            self.mass.assign(self._to_slots(np.where(plan.body >= 0, 0.0, self._mass_host).astype(np.float32)))
            self._rigid_walls = (*wall_bounds(self.origin, self.dx, self.dims, BOUNDARY_CELLS, sc.ground.enabled,
                                              sc.ground.height_m), sc.ground.friction if sc.ground.enabled else 0.0)
        self._set_stiffness(scale)
        # a softened part keeps its yield *strain*: default yield stresses (strain · E) scale too
        ys = np.where(self._yield_from_strain & (scale > 0), self._yield_base * scale, self._yield_base)
        self.yield_stress.assign(self._to_slots(ys.astype(np.float32)))
        soft = self._moving & (scale > 0)
        self.stiffness_scale = float(scale[soft].min()) if soft.any() else 1.0

    def _hold(self, held: np.ndarray) -> None:
        """Hold particles (caller's order) in place from now on, as scene.fixed would."""
        self.fixed = self.fixed | held
        self._moving = ~self.fixed
        self._moving_snow &= self._moving
        self.fixed_flag.assign(self._to_slots(self.fixed.astype(np.int32)))
        self.set_velocities(self.velocities())

    def step_frame(self, frame_dt_s: float) -> None:
        """Advance the simulation by frame_dt_s seconds in ceil(frame_dt_s / dt) substeps."""
        if not (frame_dt_s > 0.0 and math.isfinite(frame_dt_s)):
            raise InputError(f"frame duration must be a positive number of seconds, got {frame_dt_s}")
        clock = time.perf_counter
        t_start = clock()
        resort_due = self.sort_every > 0 and self.frame > 0 and self.frame % self.sort_every == 0
        if resort_due and not self.resort_inside:
            self._resort()
        t_sorted = clock()
        n_sub = self.substeps_for(frame_dt_s)
        resort_at = self._inside_resort_substep(n_sub) if resort_due and self.resort_inside else -1
        if resort_due and self.resort_inside and resort_at < 0:
            self._resort()
        t_stats = clock()
        dt = frame_dt_s / n_sub
        t0 = self.time_s
        self._clear_grid()
        for s in range(n_sub):
            if s == resort_at:  # the frame's full re-sort, issued while the device is busy
                self._resort()
                if self.kernel_timer is not None:
                    self.kernel_timer.mark("resort")
            elif self.sort_every > 0 and self._runs_p2g and s > 0 and s % self.sort_substeps == 0:
                self._reindex()  # all on the device: the launches queue behind the substeps
                if self.kernel_timer is not None:
                    self.kernel_timer.mark("sort")
            t = t0 + s * dt
            self._apply_impulses(t + dt)
            carry = self.carrying
            self._substep(dt, t, carry_in=carry and s > 0, carry_out=carry and s < n_sub - 1)
        t_launched = clock()
        self.time_s = t0 + frame_dt_s
        self.state.time_s = self.time_s
        self.frame += 1
        self.substeps_last_frame = n_sub
        self.particle_substeps += n_sub * self.n
        self._guard(dt)
        self.timing = {"sort_s": t_sorted - t_start, "stats_s": t_stats - t_sorted,
                       "launch_s": t_launched - t_stats, "guard_s": clock() - t_launched}

    @property
    def carrying(self) -> bool:
        """Whether a frame carries the affine matrices from G2P to P2G now: carry_affine, and no
        rigid bodies (they overwrite C and τ after G2P, so the next P2G must compute its own)."""
        return self.carry_affine and self.rigid is None

    def _inside_resort_substep(self, n_sub: int) -> int:
        """Substep before which `resort_inside` re-sorts the arrays: the first in-frame index sort
        at or after RESORT_SUBSTEP (by then the host, issuing launches faster than the device runs
        them, is far enough ahead that issuing the ~40 launches of a re-sort leaves the device no
        gap); -1: at the frame start (no in-frame index sorts, or too few substeps)."""
        if not self._runs_p2g:
            return -1
        at = -(-RESORT_SUBSTEP // self.sort_substeps) * self.sort_substeps
        return at if at < n_sub else -1

    def _apply_impulses(self, t_end: float) -> None:
        for i, imp in enumerate(self.scene.impulses):
            if self._impulse_done[i] or imp.time_s >= t_end:
                continue
            self._launch_impulse(imp)
            self._impulse_done[i] = True

    def _launch_impulse(self, imp) -> None:
        lo, hi = ((-FAR,) * 3, (FAR,) * 3) if imp.region is None else (imp.region.min, imp.region.max)
        wp.launch(kernels.add_velocity_in_region, dim=self.n, device=self.device,
                  inputs=[self.x, self.v, self.fixed_flag, wp.vec3(*lo), wp.vec3(*hi),
                          wp.vec3(*imp.velocity_change)])

    def _active_box(self) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        """Grid nodes the particles touch this substep (CPU: tight box; GPU: the whole grid)."""
        if self.device != "cpu":
            return (0, 0, 0), self.dims
        x = self.x.numpy()  # bounds column by column: an axis-0 reduction of (N,3) is ~15× slower
        g_lo = (np.array([x[:, i].min() for i in range(3)], np.float64) - self.origin) / self.dx
        g_hi = (np.array([x[:, i].max() for i in range(3)], np.float64) - self.origin) / self.dx
        if not (np.isfinite(g_lo).all() and np.isfinite(g_hi).all()):  # a NaN particle: the frame's guard reports it
            return (0, 0, 0), self.dims
        lo = np.maximum(np.floor(g_lo - 0.5).astype(int), 0)
        hi = np.minimum(np.floor(g_hi - 0.5).astype(int) + 3, self.dims)
        return tuple(int(a) for a in lo), tuple(int(b - a) for a, b in zip(lo, hi))  # type: ignore[return-value]

    def _record_launches(self) -> None:
        """Pack every kernel's arguments once; substeps then only update dt, time and the box.
        (The scene is read here: changing it after construction has no effect.)"""
        sc, d = self.scene, self.device
        particle_inputs = [self.x, self.v, self.C, self.stress, self.volume, self.mass, self.fixed_flag,
                           self.grid_info, 0.0]
        grid_outputs = [self.grid_mass, self.grid_momentum, self.grid_fixed]
        capped = lambda k: kernels.register_capped(k, self.p2g_max_registers)  # noqa: E731
        self._p2g_carry = None  # carry_affine: the P2G that reads the affine matrices G2P left
        if self._packed:
            kernel, kernel_carry, per_run = COLUMN_KINDS[self.p2g_kind]
            runs = [self.run_start, self.run_count, self.run_key, self._p2g_index, int(self.vector_atomics),
                    self.grid_mv, self.grid_fixed]
            threads = p2g_column.column_threads(self.n, self.column_run, self.dims, per_run)
            block = {} if self.p2g_block_dim is None else {"block_dim": int(self.p2g_block_dim)}
            self._p2g = wp.launch(capped(kernel), device=d, record_cmd=True, dim=threads,
                                  inputs=particle_inputs + runs, **block)
            if self.carry_affine:
                self._p2g_carry = wp.launch(capped(kernel_carry), device=d, record_cmd=True, dim=threads,
                                            inputs=particle_inputs + runs, **block)
        elif self.p2g_kind == "chunked":
            self._p2g = wp.launch(capped(kernels.p2g_chunked), dim=self.n, device=d, record_cmd=True,
                                  inputs=particle_inputs + [self.run_start, self.run_count, self._p2g_index]
                                  + grid_outputs)
        else:
            self._p2g = wp.launch(capped(kernels.p2g), dim=self.n, device=d, record_cmd=True,
                                  inputs=particle_inputs + grid_outputs)
        grid_in = [self.grid_mv, self.grid_fixed] if self._packed else grid_outputs
        self._grid = wp.launch(
            p2g_column.grid_update_packed if self._packed else kernels.grid_update, dim=self.dims, device=d,
            record_cmd=True,
            inputs=grid_in + [self.grid_velocity, self.grid_info,
                              wp.vec3i(0, 0, 0), 0.0, 0.0, wp.vec3(*sc.gravity), self.wind_acc, self.wind_lo,
                              self.wind_hi, self.wind_timing, len(sc.wind), sc.damping, sc.air_drag,
                              int(sc.ground.enabled), sc.ground.height_m, sc.ground.friction,
                              int(sc.walls == "sticky"), BOUNDARY_CELLS])
        self._g2p = wp.launch(
            kernels.register_capped(kernels.g2p, self.g2p_max_registers), dim=self.n, device=d, record_cmd=True,
            inputs=[self.x, self.v, self.C, self.F, self.mu, self.lam, self.yield_stress, self.material,
                    self.Jp, self.fixed_flag, self.grid_info, self.material_params, 0.0, self.grid_velocity,
                    self.stress])
        self._g2p_carry = None if not self.carry_affine else wp.launch(
            kernels.register_capped(p2g_column.g2p_carry, self.g2p_max_registers), dim=self.n, device=d,
            record_cmd=True,
            inputs=[self.x, self.v, self.C, self.F, self.mu, self.lam, self.yield_stress, self.material,
                    self.Jp, self.fixed_flag, self.grid_info, self.material_params, 0.0, self.grid_velocity,
                    self.stress, self.volume, self.mass])

    def _clear_grid(self) -> None:
        """Zero the P2G sums (the grid update clears them after each substep)."""
        for a in (self.grid_mass, self.grid_momentum, self.grid_mv, self.grid_fixed):
            if a is not None:
                a.zero_()

    def _substep(self, dt: float, t: float, carry_in: bool = False, carry_out: bool = False) -> None:
        """One substep of dt s at time t. carry_in: the P2G reads the affine matrices the last G2P
        left in `stress` (carry_affine); carry_out: this G2P leaves them for the next substep."""
        timer = self.kernel_timer
        p2g = self._p2g_carry if carry_in else self._p2g
        p2g.set_param_by_name("dt", dt)
        p2g.launch()
        if timer is not None:
            timer.mark("p2g")
        box_lo, box_shape = self._active_box()
        self._grid.set_dim(box_shape)
        self._grid.set_param_by_name("box_lo", wp.vec3i(*box_lo))
        self._grid.set_param_by_name("dt", dt)
        self._grid.set_param_by_name("time_s", t)
        if self.rigid is not None:  # nodes the bodies cover, impulses, node masses (sim/rigid.py)
            if self._packed:
                wp.launch(p2g_column.packed_mass, dim=self.dims, device=self.device,
                          inputs=[self.grid_mv, self.grid_mass])
            self.rigid.before_grid(self.x, self.v, self.order, self.grid_info, self.grid_mass, self.grid_fixed,
                                   self._rigid_walls[0][2], dt)
        self._grid.launch()
        if timer is not None:
            timer.mark("grid")
        if self.rigid is not None:  # momentum in from the grid, one rigid step (sim/rigid.py)
            self.rigid.advance(self.grid_info, self.grid_velocity, box_lo, box_shape, *self._rigid_walls, dt)
        g2p = self._g2p_carry if carry_out else self._g2p
        g2p.set_param_by_name("dt", dt)
        g2p.launch()
        if self.rigid is not None:  # velocity out: rigid particles take their body's motion
            self.rigid.place(self.x, self.v, self.C, self.F, self.stress, self.order)
        if timer is not None:
            timer.mark("g2p")

    # ------------------------------------------------------------------ guard and results
    def _guard(self, dt: float) -> None:
        """Raise ComputationError if any particle's state is non-finite or has run away
        (a device reduction: only per-material counts come back)."""
        v_limit = self.dx / dt  # one cell per substep: beyond this the explicit scheme has failed
        counts_all = self.frame_stats(v_limit).bad_per_material
        if not counts_all.any():
            return
        ids = np.nonzero(counts_all)[0]
        counts = counts_all[ids]
        worst = int(ids[np.argmax(counts)])
        names = ", ".join(f"'{MATERIAL_NAMES[int(m)]}' ({int(c)})" for m, c in zip(ids, counts))
        raise ComputationError(
            f"simulation diverged at frame {self.frame} (t={self.time_s:.4g} s): material "
            f"'{MATERIAL_NAMES[worst]}' particles ({int(counts.sum())} of {self.n}: {names}) reached non-finite "
            f"or runaway velocity/deformation (limit {v_limit:.3g} m/s, ‖F‖ ≤ {MAX_STRETCH:g}); "
            "lower solver.cfl or check E/nu/density")

    def positions(self) -> np.ndarray:
        """Particle positions (N,3) float32, world m, in the caller's particle order."""
        return self._to_caller(self.x.numpy())

    def velocities(self) -> np.ndarray:
        """Particle velocities (N,3) float32, m/s, in the caller's particle order."""
        return self._to_caller(self.v.numpy())

    def deformation_gradients(self) -> np.ndarray:
        """Deformation gradients F (N,3,3) float32 (elastic part for plastic materials)."""
        return self._to_caller(self.F.numpy())

    def plastic_volume_ratio(self) -> np.ndarray:
        """Jp (N,) — plastic volume change of snow particles (1 elsewhere)."""
        return self._to_caller(self.Jp.numpy())

    def yield_stresses(self) -> np.ndarray:
        """Yield stress (N,) float32 Pa the kernels use (after any stiffness cap)."""
        return self._to_caller(self.yield_stress.numpy())

    def set_velocities(self, v_mps: np.ndarray) -> None:
        """Overwrite the particle velocities ((N,3) m/s, caller's order); fixed particles keep 0."""
        v = np.where(self.fixed[:, None], 0.0, np.broadcast_to(v_mps, (self.n, 3))).astype(np.float32)
        self.v.assign(self._to_slots(v))

    def set_plastic_volume_ratio(self, jp: np.ndarray) -> None:
        """Overwrite Jp ((N,), caller's order), e.g. to start from compacted snow."""
        self.Jp.assign(self._to_slots(np.asarray(jp, np.float32).reshape(self.n)))
