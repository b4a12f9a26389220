"""Batched simulation: K independent runs on one grid shape advanced by ONE set of launches.

Why: diagnose simulates 30–60 candidate variants of one object (a drag coefficient, a part's
stiffness, ...). Each run of a few thousand particles is launch-bound on a GPU (a substep is three
tiny kernels), so K runs one after the other cost K× the launch overhead; batched, they cost about
one run's. The runs share a State (sim/state.py) — run r owns the particle slots
offsets[r] ≤ p < offsets[r+1] — and a 4-D grid (one grid per run, so no run feels another), and
each keeps its own scene forces, material arrays, substep count (CFL), impulses, stiffness cap
and divergence guard: a batched run takes the same substeps with the same dt as it would alone
(batch_kernels.py). A run that diverges is stopped and reported; the others go on. A run with a
part stiffer than the substep budget allows is stopped at once and `simulate_batch` runs it
alone, so the unbatched MPMSolver decides what that part becomes (rigid body or softened).

Runs must share the grid (domain origin, cell size, node counts), walls, constitutive settings
(scene.materials) and solver settings; everything else may differ.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..errors import ComputationError, InputError
from ..materials import MATERIAL_NAMES, SNOW
from ..progress import progress
from ..splat import SplatCloud
from . import batch_kernels as bk
from . import kernels
from .particles import Particles
from .scene import BOUNDARY_CELLS, Scene
from .solver import FAR, MAX_STRETCH, MPMSolver, held_particles, lame_parameters, p_wave_speed, yield_stresses
from .state import State


CUDA_GRAPH = True  # default of BatchedSolver(graph=None): on a GPU, replay each substep as one CUDA
# graph (four launches for one: a batch of small runs is launch-bound; tested against plain launches)
DEVICE_LOOP = False  # default of simulate_batch(device_loop=None): frames planned, stepped and guarded on
# the device, nothing read back until the end (device_frames.py; on a GPU where conditional graphs exist)
GRAPH_SUBSTEPS = 4  # ... and GRAPH_SUBSTEPS substeps as one more graph: a frame of n substeps is
# n // GRAPH_SUBSTEPS replays of that one plus n % GRAPH_SUBSTEPS of the single-substep graph


def batch_key(scene: Scene) -> tuple:
    """What runs of one batch must share (grid, walls, materials and solver settings)."""
    m, s = scene.materials, scene.solver
    return (tuple(np.round(scene.domain_origin(), 9)), round(scene.dx, 12), tuple(scene.grid_dims), scene.walls,
            repr(sorted(vars(m).items())), repr(sorted(vars(s).items())))


@dataclass
class _Run:
    """Host-side bookkeeping of one run (arrays in its own particle order)."""

    scene: Scene
    start: int
    stop: int
    E: np.ndarray
    nu: np.ndarray
    wave_speed: np.ndarray
    moving: np.ndarray
    moving_snow: np.ndarray
    wind_peak: float
    accel: float = 0.0  # |gravity| + peak wind acceleration, m/s² (bounds a frame's speed-up)
    has_snow: bool = False  # moving_snow.any(), asked every frame
    c_static: float = 0.0
    alive: bool = True
    error: ComputationError | None = None
    over_budget: bool = False  # a part needed more substeps than allowed: stopped, to be run alone
    substeps_last_frame: int = 0
    dt: float = math.inf


class BatchedSolver:
    """K MLS-MPM runs in one particle set and one launch per kernel and substep.

    `runs`: (Particles, Scene) per run, world units (m, s, kg, Pa). Attributes: state (all
    particles, run after run), offsets (K+1,), time_s, frame, errors (per run: None or the
    ComputationError that stopped it), substeps_last_frame (per run).
    """

    def __init__(self, runs: list[tuple[Particles, Scene]], device: str = "cpu", graph: bool | None = None) -> None:
        """`graph`: on a GPU, replay each substep's launches as one captured CUDA graph
        (None: the module default CUDA_GRAPH); ignored on the CPU."""
        from ..devices import resolve_warp_device

        if not runs:
            raise InputError("a batch needs at least one run")
        key = batch_key(runs[0][1])
        for i, (_, sc) in enumerate(runs):
            if batch_key(sc) != key:
                raise InputError(f"run {i} does not share run 0's grid, walls, materials or solver settings; "
                                 "batch only runs on the same grid")
        self.device = d = resolve_warp_device(device)
        self.scene = scene = runs[0][1]
        self.k = len(runs)
        self.dx = scene.dx
        self.dims = scene.grid_dims
        self.origin = scene.domain_origin()
        counts = [len(p) for p, _ in runs]
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.n = int(self.offsets[-1])
        self.time_s = 0.0
        self.frame = 0
        self._runs: list[_Run] = []
        fixed_all, ys_all, x_all, v_all = [], [], [], []
        for r, (p, sc) in enumerate(runs):
            p.validate()
            MPMSolver._check_inside(self, p.x)
            fixed = held_particles(p, sc)
            ys, _ = yield_stresses(p, sc)
            moving = ~fixed
            winds = sum(float(np.linalg.norm(w.acceleration)) * (1.0 + w.gust_amplitude) for w in sc.wind)
            self._runs.append(_Run(sc, int(self.offsets[r]), int(self.offsets[r + 1]), p.E.astype(np.float64),
                                   p.nu.astype(np.float64), p_wave_speed(p.E, p.nu, p.density), moving,
                                   moving & (p.material_id == SNOW), winds))
            fixed_all.append(fixed)
            ys_all.append(ys)
            x_all.append(p.x)
            v_all.append(np.where(fixed[:, None], 0.0, p.v))
        cat = np.concatenate
        self.material_id = cat([p.material_id for p, _ in runs]).astype(np.int32)
        self.fixed = cat(fixed_all)
        self.state = State.at_rest(cat(x_all), cat(v_all).astype(np.float32), d)
        self.volume = wp.array(cat([p.volume for p, _ in runs]), dtype=float, device=d)
        self.mass = wp.array(cat([p.mass for p, _ in runs]), dtype=float, device=d)
        self.mu = wp.zeros(self.n, dtype=float, device=d)
        self.lam = wp.zeros(self.n, dtype=float, device=d)
        self.wave_c = wp.zeros(self.n, dtype=float, device=d)
        self.yield_stress = wp.array(cat(ys_all).astype(np.float32), dtype=float, device=d)
        self.material = wp.array(self.material_id, dtype=wp.int32, device=d)
        self.fixed_flag = wp.array(self.fixed.astype(np.int32), dtype=wp.int32, device=d)
        self.run = wp.array(np.repeat(np.arange(self.k, dtype=np.int32), counts), dtype=wp.int32, device=d)
        for run in self._runs:
            self._set_stiffness(run)
            run.accel = float(np.linalg.norm(run.scene.gravity)) + run.wind_peak
            run.has_snow = bool(run.moving_snow.any())
        # the same per-run figures as arrays, for planning every run's substeps at once (_plan)
        self._c_static = np.array([run.c_static for run in self._runs], np.float64)
        self._accel = np.array([run.accel for run in self._runs], np.float64)
        self._has_snow = np.array([run.has_snow for run in self._runs], bool)
        self._alive = np.ones(self.k, bool)  # mirror of run.alive (set through _stop)
        shape = (self.k,) + tuple(self.dims)
        self.grid_mass = wp.zeros(shape, dtype=float, device=d)
        self.grid_momentum = wp.zeros(shape, dtype=wp.vec3, device=d)
        self.grid_fixed = wp.zeros(shape, dtype=float, device=d)
        self.grid_velocity = wp.zeros(shape, dtype=wp.vec3, device=d)
        self.grid_info = kernels.GridInfo()
        self.grid_info.origin = wp.vec3(*self.origin)
        self.grid_info.dx = self.dx
        self.grid_info.inv_dx = 1.0 / self.dx
        self.grid_info.dims = wp.vec3i(*self.dims)
        self.material_params = MPMSolver._material_params(self)  # reads only self.scene.materials
        self.forces = self._forces([sc for _, sc in runs])
        self.n_sub = wp.zeros(self.k, dtype=wp.int32, device=d)
        self.dt_run = wp.zeros(self.k, dtype=float, device=d)
        self.dt_run64 = wp.zeros(self.k, dtype=wp.float64, device=d)
        self.alive_flag = wp.ones(self.k, dtype=wp.int32, device=d)
        self.v_limit = wp.full(self.k, FAR, dtype=float, device=d)
        self.maxima = wp.zeros((self.k, 2), dtype=float, device=d)
        self.substep = wp.zeros(1, dtype=wp.int32, device=d)  # read by the kernels (graph-friendly)
        self.frame_start = wp.zeros(1, dtype=wp.float64, device=d)  # s
        self._substep_host = self.substep.numpy() if d == "cpu" else None  # a view on the CPU
        self.bad = wp.zeros((self.k, 7), dtype=wp.int32, device=d)
        self._pending = [(r, i) for r, run in enumerate(self._runs) for i in range(len(run.scene.impulses))]
        self._stats: tuple[np.ndarray, np.ndarray] | None = None
        self.fetch_positions = False  # GPU: bring x back with every frame's statistics (one sync)
        self._pinned: dict[int, wp.array] = {}      # GPU: page-locked host mirrors (async copies)
        self._uploaded: dict[int, np.ndarray] = {}  # last values sent per device array
        self._x_host: np.ndarray | None = None       # positions fetched at the end of frame _x_frame
        self._x_frame = -1
        self.substeps_total = 0                      # substep launches so far (all runs together)
        self.wait_s = 0.0                            # GPU: host time spent waiting in end-of-frame syncs
        self._record_launches()
        self.graph = None                    # one substep (p2g, grid, g2p, substep += 1)
        self.graph_unrolled = None           # GRAPH_SUBSTEPS substeps
        if d != "cpu" and (CUDA_GRAPH if graph is None else graph):
            self.graph = self._capture(1)
            if GRAPH_SUBSTEPS > 1:
                self.graph_unrolled = self._capture(GRAPH_SUBSTEPS)

    # ------------------------------------------------------------------ set-up
    def _capture(self, substeps: int):
        """A CUDA graph of `substeps` consecutive substeps' launches."""
        wp.capture_begin(device=self.device, force_module_load=True)
        try:
            for _ in range(substeps):
                self._p2g.launch()
                self._grid.launch()
                self._g2p.launch()
                self._next.launch()
        finally:
            graph = wp.capture_end(device=self.device)
        return graph

    def _forces(self, scenes: list[Scene]) -> bk.RunForces:
        d = self.device
        f = bk.RunForces()
        f.gravity = wp.array(np.array([sc.gravity for sc in scenes], np.float32), dtype=wp.vec3, device=d)
        f.damping = wp.array(np.array([sc.damping for sc in scenes], np.float32), dtype=float, device=d)
        f.air_drag = wp.array(np.array([sc.air_drag for sc in scenes], np.float32), dtype=float, device=d)
        f.ground_enabled = wp.array(np.array([int(sc.ground.enabled) for sc in scenes], np.int32), dtype=wp.int32,
                                    device=d)
        f.ground_height = wp.array(np.array([sc.ground.height_m for sc in scenes], np.float32), dtype=float, device=d)
        f.friction = wp.array(np.array([sc.ground.friction for sc in scenes], np.float32), dtype=float, device=d)
        first, acc, lo, hi, timing = [0], [], [], [], []
        for sc in scenes:
            for w in sc.wind:
                acc.append(w.acceleration)
                lo.append((-FAR,) * 3 if w.region is None else w.region.min)
                hi.append((FAR,) * 3 if w.region is None else w.region.max)
                timing.append((w.start_s, FAR if w.end_s is None else w.end_s, w.gust_amplitude, w.gust_frequency_hz))
            first.append(len(acc))
        if not acc:  # Warp arrays of length 0 are fine, but keep one harmless entry for clarity
            acc, lo, hi, timing = [(0.0,) * 3], [(0.0,) * 3], [(0.0,) * 3], [(0.0,) * 4]
        f.wind_first = wp.array(np.array(first, np.int32), dtype=wp.int32, device=d)
        f.wind_acc = wp.array(np.array(acc, np.float32), dtype=wp.vec3, device=d)
        f.wind_lo = wp.array(np.array(lo, np.float32), dtype=wp.vec3, device=d)
        f.wind_hi = wp.array(np.array(hi, np.float32), dtype=wp.vec3, device=d)
        f.wind_timing = wp.array(np.array(timing, np.float32), dtype=wp.vec4, device=d)
        return f

    def _record_launches(self) -> None:
        d, st = self.device, self.state
        self._p2g = wp.launch(bk.p2g_batched, dim=self.n, device=d, record_cmd=True,
                              inputs=[st.x, st.v, st.C, st.stress, self.volume, self.mass, self.fixed_flag, self.run,
                                      self.grid_info, self.dt_run, self.n_sub, self.substep, self.grid_mass,
                                      self.grid_momentum, self.grid_fixed])
        self._grid = wp.launch(bk.grid_update_batched, dim=(self.k,) + tuple(self.dims), device=d, record_cmd=True,
                               inputs=[self.grid_mass, self.grid_momentum, self.grid_fixed, self.grid_velocity,
                                       self.grid_info, wp.vec3i(0, 0, 0), self.dt_run, self.n_sub, self.substep,
                                       self.frame_start, self.dt_run64, self.forces, int(self.scene.walls == "sticky"),
                                       BOUNDARY_CELLS])
        self._g2p = wp.launch(bk.g2p_batched, dim=self.n, device=d, record_cmd=True,
                              inputs=[st.x, st.v, st.C, st.F, self.mu, self.lam, self.yield_stress, self.material,
                                      st.Jp, self.fixed_flag, self.run, self.grid_info, self.material_params,
                                      self.dt_run, self.n_sub, self.substep, self.grid_velocity, st.stress])
        self._next = wp.launch(bk.advance_substep, dim=1, device=d, record_cmd=True, inputs=[self.substep, 1, 1])
        self._first = wp.launch(bk.advance_substep, dim=1, device=d, record_cmd=True, inputs=[self.substep, 0, 0])
        self._stats_launch = wp.launch(bk.run_stats, dim=self.n, device=d, record_cmd=True,
                                       inputs=[st.x, st.v, st.F, st.Jp, self.material, self.fixed_flag, self.wave_c,
                                               self.run, self.alive_flag, self.scene.materials.snow_hardening,
                                               self.v_limit, MAX_STRETCH, self.maxima, self.bad])
        self._box_arg = self._arg_index(self._grid, "box_lo")

    @staticmethod
    def _arg_index(launch: wp.Launch, name: str) -> int:
        return [arg.label for arg in launch.kernel.adj.args].index(name)

    def _set_stiffness(self, run: _Run) -> None:
        """Upload μ, λ and the wave speed of one run's particles (as MPMSolver._set_stiffness; a
        batch never softens: a run over the substep budget is stopped and run alone)."""
        mu, lam = lame_parameters(run.E, run.nu)
        c = run.wave_speed
        a, b = run.start, run.stop
        self.mu[a:b].assign(mu.astype(np.float32))
        self.lam[a:b].assign(lam.astype(np.float32))
        self.wave_c[a:b].assign(c.astype(np.float32))
        static = run.moving & ~run.moving_snow
        run.c_static = float(c[static].max()) if static.any() else 0.0

    # ------------------------------------------------------------------ per-run CFL (as MPMSolver)
    def _cfl_dt(self, c_mps: float) -> float:
        return math.inf if c_mps == 0.0 else self.scene.solver.cfl * self.dx / c_mps

    def _wave_speed(self, run: _Run, snow_wave: float) -> float:
        return max(run.c_static, snow_wave) if run.has_snow else run.c_static

    def _substeps(self, r: int, frame_dt_s: float, max_speed: float, snow_wave: float) -> int:
        """Substeps run r takes in its next frame (as MPMSolver plans them; 0: over the budget) —
        the plain per-run reference of _plan, which step_frame uses (tested equal)."""
        run = self._runs[r]
        s = self.scene.solver
        dt = self._cfl_dt(self._wave_speed(run, snow_wave))
        n_elastic = math.ceil(frame_dt_s / dt) if math.isfinite(dt) else 1
        if n_elastic > s.max_substeps_per_frame:
            return 0  # over the budget: the caller runs it alone (MPMSolver's stiff-part handling)
        kicks = sum(float(np.linalg.norm(run.scene.impulses[i].velocity_change)) for rr, i in self._pending
                    if rr == r and run.scene.impulses[i].time_s < self.time_s + frame_dt_s) if self._pending else 0.0
        v_bound = max_speed + run.accel * frame_dt_s + kicks
        n_velocity = math.ceil(frame_dt_s * v_bound / (s.velocity_cfl * self.dx))
        return int(min(max(1, n_elastic, n_velocity), s.max_substeps_per_frame))

    def _plan(self, frame_dt_s: float, maxima: np.ndarray) -> np.ndarray:
        """_substeps of every run at once (0 for runs not alive, and for runs over the substep
        budget): the same float64 operations in the same order, elementwise, so the same counts."""
        s = self.scene.solver
        snow = maxima[:, 1]
        c = np.where(self._has_snow, np.maximum(self._c_static, snow), self._c_static)
        with np.errstate(divide="ignore"):
            dt = np.where(c == 0.0, math.inf, s.cfl * self.dx / np.where(c == 0.0, 1.0, c))
        n_elastic = np.where(np.isfinite(dt), np.ceil(frame_dt_s / dt), 1.0)
        kicks = np.zeros(self.k)
        if self._pending:
            for r in range(self.k):
                run = self._runs[r]
                kicks[r] = sum(float(np.linalg.norm(run.scene.impulses[i].velocity_change)) for rr, i in self._pending
                               if rr == r and run.scene.impulses[i].time_s < self.time_s + frame_dt_s)
        v_bound = maxima[:, 0] + self._accel * frame_dt_s + kicks
        n_velocity = np.ceil(frame_dt_s * v_bound / (s.velocity_cfl * self.dx))
        n = np.minimum(np.maximum(np.maximum(1.0, n_elastic), n_velocity), s.max_substeps_per_frame)
        n = np.where(n_elastic > s.max_substeps_per_frame, 0.0, n)
        return np.where(self._alive, n, 0.0).astype(np.int32)

    # ------------------------------------------------------------------ host <-> device
    def _host_mirror(self, a: wp.array) -> wp.array:
        """A page-locked host array shaped like device array `a` (made once)."""
        buf = self._pinned.get(id(a))
        if buf is None:
            buf = self._pinned[id(a)] = wp.empty(a.shape, dtype=a.dtype, device="cpu", pinned=True)
        return buf

    def _upload(self, a: wp.array, values: np.ndarray) -> None:
        """a ← values, skipped when they are the ones sent last. On a GPU through a page-locked
        mirror, so the copy is queued without waiting for the substeps in flight (every mirror is
        written once per frame and each frame ends in a sync, so a queued copy has run before its
        mirror is written again)."""
        last = self._uploaded.get(id(a))
        if last is not None and last.shape == values.shape and np.array_equal(last, values):
            return
        self._uploaded[id(a)] = values.copy()
        if self.device == "cpu":
            a.assign(values)
            return
        buf = self._host_mirror(a)
        buf.numpy()[...] = values
        wp.copy(a, buf)

    def _fetch(self, arrays: list[wp.array]) -> list[np.ndarray]:
        """Host views of `arrays`, valid until the next _fetch: on a GPU copied into page-locked
        mirrors and waited for ONCE (one sync for all), on the CPU the arrays themselves."""
        if self.device == "cpu":
            return [a.numpy() for a in arrays]
        bufs = [self._host_mirror(a) for a in arrays]
        for buf, a in zip(bufs, arrays):
            wp.copy(buf, a)
        start = time.perf_counter()
        wp.synchronize_device(self.device)
        self.wait_s += time.perf_counter() - start
        return [buf.numpy() for buf in bufs]

    # ------------------------------------------------------------------ stepping
    def _reduce(self, v_limits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-run (maxima (K,2): fastest particle, fastest snow wave; bad (K,7) per material);
        with `fetch_positions` on a GPU, the positions come back in the same sync."""
        self._upload(self.v_limit, v_limits.astype(np.float32))
        self._upload(self.alive_flag, self._alive.astype(np.int32))
        self.maxima.zero_()
        self.bad.zero_()
        st = self.state
        self._stats_launch.launch()
        with_x = self.fetch_positions and self.device != "cpu"
        out = self._fetch([self.maxima, self.bad] + ([st.x] if with_x else []))
        if with_x:
            self._x_host, self._x_frame = out[2], self.frame
        return out[0].astype(np.float64), out[1].copy()

    @property
    def alive(self) -> np.ndarray:
        """Per run: still being simulated (a copy)."""
        return self._alive.copy()

    def _stop(self, r: int) -> None:
        self._runs[r].alive = False
        self._alive[r] = False

    @property
    def errors(self) -> list[ComputationError | None]:
        return [r.error for r in self._runs]

    @property
    def substeps_last_frame(self) -> list[int]:
        return [r.substeps_last_frame for r in self._runs]

    @property
    def over_budget(self) -> list[bool]:
        """Per run: stopped because a part needs more than solver.max_substeps_per_frame (the
        unbatched MPMSolver decides what such parts become: rigid, softened or an error)."""
        return [r.over_budget for r in self._runs]

    def dt(self, r: int) -> float:
        """Largest stable substep (s) of run r from the elastic CFL (as MPMSolver.dt)."""
        run = self._runs[r]
        snow = float(self._stats[0][r, 1]) if self._stats is not None else 0.0
        return self._cfl_dt(self._wave_speed(run, snow))

    def step_frame(self, frame_dt_s: float) -> None:
        """Advance every live run by frame_dt_s seconds, each in its own ceil(frame_dt_s / dt_r)
        substeps; a run that diverges is stopped (errors[r]) and the others continue."""
        if not (frame_dt_s > 0.0 and math.isfinite(frame_dt_s)):
            raise InputError(f"frame duration must be a positive number of seconds, got {frame_dt_s}")
        if self._stats is None:
            self._stats = self._reduce(np.full(self.k, FAR))
        n_sub = self._plan(frame_dt_s, self._stats[0])
        for r in np.nonzero(self._alive & (n_sub == 0))[0]:
            self._stop(int(r))
            self._runs[r].over_budget = True
        dts = np.where(n_sub > 0, frame_dt_s / np.maximum(n_sub, 1), 0.0)
        self._upload(self.n_sub, n_sub)
        self._upload(self.dt_run, dts.astype(np.float32))
        self._upload(self.dt_run64, dts)
        t0 = self.time_s
        self._upload(self.frame_start, np.array([t0], np.float64))
        if self._substep_host is not None:
            self._substep_host[0] = 0
        else:
            self._first.launch()
        # no grid clearing: the grids start at zero and every grid launch clears the nodes it read
        # (all nodes P2G can have touched: a run's own nodes, on the CPU the live particles' box)
        alive_slots = None
        if self.device == "cpu" and not self._alive.all():
            alive_slots = np.repeat(self._alive, np.diff(self.offsets))
        n_max = int(n_sub.max(initial=0))
        if self.graph_unrolled is not None and not self._pending:  # no impulse to apply between substeps
            whole, rest = divmod(n_max, GRAPH_SUBSTEPS)
            for _ in range(whole):
                wp.capture_launch(self.graph_unrolled)
            for _ in range(rest):
                wp.capture_launch(self.graph)
        else:
            for s in range(n_max):
                self._apply_impulses(s, t0, n_sub, dts)
                self._launch_substep(s, alive_slots)
        self.substeps_total += n_max
        self.time_s = t0 + frame_dt_s
        self.state.time_s = self.time_s
        self.frame += 1
        for r, run in enumerate(self._runs):
            run.substeps_last_frame = int(n_sub[r])
            if self._alive[r]:
                run.dt = float(dts[r])
        v_limits = np.where(n_sub > 0, self.dx / np.where(dts > 0, dts, 1.0), FAR)
        self._stats = self._reduce(v_limits)
        self._guard(self._stats[1], v_limits)

    def _apply_impulses(self, s: int, t0: float, n_sub: np.ndarray, dts: np.ndarray) -> None:
        if not self._pending:
            return
        still = []
        for r, i in self._pending:
            run = self._runs[r]
            imp = run.scene.impulses[i]
            if not run.alive:
                continue
            if s >= n_sub[r] or imp.time_s >= (t0 + s * dts[r]) + dts[r]:
                still.append((r, i))
                continue
            lo, hi = ((-FAR,) * 3, (FAR,) * 3) if imp.region is None else (imp.region.min, imp.region.max)
            a, b = run.start, run.stop
            wp.launch(kernels.add_velocity_in_region, dim=b - a, device=self.device,
                      inputs=[self.state.x[a:b], self.state.v[a:b], self.fixed_flag[a:b], wp.vec3(*lo),
                              wp.vec3(*hi), wp.vec3(*imp.velocity_change)])
        self._pending = still

    def _launch_substep(self, s: int, alive_slots: np.ndarray | None) -> None:
        """Substep `s` (the kernels read it from self.substep): three launches that never change
        their arguments on a GPU (launch-bound there: replayed as one CUDA graph when `graph`);
        on the CPU the grid launch covers the live particles' box."""
        if self.graph is not None:
            wp.capture_launch(self.graph)  # p2g, grid, g2p, substep += 1
            return
        if self._substep_host is not None:
            self._substep_host[0] = s
            lo, shape = self._active_box(alive_slots)
            self._grid.set_dim((self.k,) + shape)
            self._grid.set_param_at_index(self._box_arg, wp.vec3i(*lo))
        self._p2g.launch()
        self._grid.launch()
        self._g2p.launch()
        if self._substep_host is None:
            self._next.launch()

    def _active_box(self, alive_slots: np.ndarray | None) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        """Nodes any live run's particles touch (CPU: the union of tight boxes; GPU: the grid)."""
        if self.device != "cpu":
            return (0, 0, 0), tuple(self.dims)  # type: ignore[return-value]
        x = self.state.x.numpy()
        if alive_slots is not None:
            x = x[alive_slots]
        if len(x) == 0:
            return (0, 0, 0), (1, 1, 1)
        # bounds first, then to cells, column by column (numpy's axis-0 reduction of an (N,3)
        # array is ~15× slower than three 1-D ones); no N×3 temporaries
        g_lo = (np.array([x[:, i].min() for i in range(3)], np.float64) - self.origin) / self.dx
        g_hi = (np.array([x[:, i].max() for i in range(3)], np.float64) - self.origin) / self.dx
        lo = np.maximum(np.floor(g_lo - 0.5).astype(int), 0)
        hi = np.minimum(np.floor(g_hi - 0.5).astype(int) + 3, self.dims)
        return tuple(int(a) for a in lo), tuple(int(b - a) for a, b in zip(lo, hi))  # type: ignore[return-value]

    def _guard(self, bad: np.ndarray, v_limits: np.ndarray) -> None:
        """Stop every live run with particles that went non-finite or ran away (MPMSolver._guard)."""
        if not bad.any():  # the usual frame: one test instead of one per run
            return
        for r, run in enumerate(self._runs):
            if run.alive and bad[r].any():
                self._diverged(r, bad[r], self.frame, self.time_s, float(v_limits[r]))

    def _diverged(self, r: int, counts_all: np.ndarray, frame: int, time_s: float, v_limit: float) -> None:
        """Stop run r: `counts_all` of its particles per material failed the guard at the end of
        frame `frame` (time_s), against velocity limit `v_limit` m/s."""
        run = self._runs[r]
        ids = np.nonzero(counts_all)[0]
        counts = counts_all[ids]
        worst = int(ids[np.argmax(counts)])
        names = ", ".join(f"'{MATERIAL_NAMES[int(m)]}' ({int(c)})" for m, c in zip(ids, counts))
        self._stop(r)
        run.error = ComputationError(
            f"simulation diverged at frame {frame} (t={time_s:.4g} s): material "
            f"'{MATERIAL_NAMES[worst]}' particles ({int(counts.sum())} of {run.stop - run.start}: {names}) "
            f"reached non-finite or runaway velocity/deformation (limit {v_limit:.3g} m/s, "
            f"‖F‖ ≤ {MAX_STRETCH:g}); lower solver.cfl or check E/nu/density")

    # ------------------------------------------------------------------ results
    def _host_positions(self) -> np.ndarray:
        """Every particle's position on the host: the copy fetched with this frame's statistics when
        there is one (GPU, `fetch_positions`), else read from the device now."""
        return self._x_host if self._x_frame == self.frame and self._x_host is not None else self.state.x.numpy()

    def positions(self, r: int | None = None) -> np.ndarray:
        """Positions (N_r,3) float32 world m of run r (None: every particle, run after run)."""
        x = self._host_positions()
        return x.copy() if r is None else x[self.offsets[r]:self.offsets[r + 1]].copy()

    def positions_at(self, slots: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Positions (len(slots),3) float32 world m of the given particle slots (all runs' numbering),
        written into `out` when given."""
        return np.take(self._host_positions(), slots, axis=0, out=out)

    def deformation_gradients(self, r: int) -> np.ndarray:
        """F (N_r,3,3) float32 of run r."""
        return self.state.F.numpy()[self.offsets[r]:self.offsets[r + 1]].copy()

    def velocities(self, r: int) -> np.ndarray:
        """Velocities (N_r,3) float32 m/s of run r."""
        return self.state.v.numpy()[self.offsets[r]:self.offsets[r + 1]].copy()


def simulate_batch(models: list[tuple[SplatCloud, Scene]], frames: int, fps: float, device: str = "auto",
                   fill: bool = False, quiet: bool = True, graph: bool | None = None,
                   points: np.ndarray | None = None, stats: dict | None = None,
                   device_loop: bool | None = None) -> list:
    """`sim.run.simulate` for several (cloud, scene) models at once, on one shared grid shape:
    one Trajectory per model, or the ComputationError that stopped that model's run (the others
    still finish). Raises InputError for unusable input (as simulate does). `points`: indices of
    the Gaussians to return (Trajectory.x is then (T, len(points), 3)): diagnose needs only the
    tracked ones, and mapping every Gaussian back to input coordinates each frame costs more
    host time than a batched GPU frame. `stats` (optional) receives where the time went: set-up
    (particles and solver) and frame-loop seconds, substeps launched, seconds waited in syncs.
    `device_loop`: once no impulse is pending, run the remaining frames with nothing read back
    until the end (device_frames.py; None: DEVICE_LOOP; where the device cannot, step_frame)."""
    from .run import Trajectory, build_particles, simulate

    start = time.perf_counter()

    if frames < 1:
        raise InputError(f"frames must be ≥ 1, got {frames}")
    if not fps > 0:
        raise InputError(f"fps must be > 0, got {fps}")
    built = [build_particles(cloud, scene, fill=fill) for cloud, scene in models]
    solver = BatchedSolver([(p, sc) for (p, _), (_, sc) in zip(built, models)], device, graph=graph)
    solver.fetch_positions = True  # read every frame: with the frame's statistics, one sync
    t = np.arange(frames, dtype=np.float64) / fps
    ns = [len(cloud) for cloud, _ in models]
    pick = [np.arange(n) if points is None else np.asarray(points, np.int64) for n in ns]
    x0_in = [cloud.means[k].astype(np.float32) for (cloud, _), k in zip(models, pick)]
    x0_world = [p.x[k].astype(np.float64) for (p, _), k in zip(built, pick)]
    slots = np.concatenate([int(solver.offsets[r]) + k for r, k in enumerate(pick)])
    ends = np.cumsum([len(k) for k in pick])
    picked = np.empty((frames, len(slots), 3), np.float32)  # every run's picked points, run after run
    loop_start = time.perf_counter()
    steps = range(1, frames) if quiet else progress(range(1, frames), desc=f"simulate ×{len(models)}",
                                                    total=frames - 1, unit="frame")
    # per frame only ONE gather of the picked world positions (the GPU idles while the host works
    # between frames; a stopped run's rows go stale, unused: it returns its error or runs alone);
    # split per run and mapped to input coordinates once at the end
    if device_loop is None:
        device_loop = DEVICE_LOOP
    if device_loop:
        from .device_frames import device_loop_available

        device_loop = device_loop_available(solver.device)
    for i in steps:
        if device_loop and not solver._pending:
            from .device_frames import DeviceFrames

            picked[i:] = DeviceFrames(solver, 1.0 / fps, slots, frames).run(frames - i)
            break
        solver.step_frame(1.0 / fps)
        solver.positions_at(slots, out=picked[i])
        if not solver.alive.any():
            break
    xs = [np.ascontiguousarray(picked[:, e - len(k):e]) for k, e in zip(pick, ends)]
    del picked
    if stats is not None:
        stats.update(setup_s=loop_start - start, loop_s=time.perf_counter() - loop_start,
                     substeps=solver.substeps_total, wait_s=solver.wait_s, frames=solver.frame)
    out: list = []
    for r, (_, tf) in enumerate(built):
        err = solver.errors[r]
        if err is not None:
            out.append(err)
            continue
        if not solver.over_budget[r]:  # alive to the end: every frame holds world positions
            xs[r][0] = x0_in[r]
            step = max(1, 4_000_000 // max(3 * len(pick[r]), 1))  # frames per float64 temporary (~32 MB)
            for a in range(1, frames, step):
                xw = xs[r][a:a + step]
                xs[r][a:a + step] = x0_in[r] + tf.displacement_to_input(xw - x0_world[r]).astype(np.float32)
        if solver.over_budget[r]:  # stiff parts: the unbatched solver decides (rigid / softened / error)
            try:
                alone = simulate(*models[r], frames, fps, device=device, fill=fill, quiet=True)
                alone.x = alone.x[:, pick[r]]
                out.append(alone)
            except ComputationError as error:
                out.append(error)
            continue
        out.append(Trajectory(t=t, x=xs[r], transform=tf, dt_s=float(solver.dt(r)),
                              substeps_per_frame=int(solver.substeps_last_frame[r]),
                              filled=len(built[r][0]) - ns[r]))
    return out


__all__ = ["BatchedSolver", "batch_key", "simulate_batch"]
