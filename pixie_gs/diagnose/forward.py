"""The forward model that diagnosis fits: simulate a (scene, cloud) and read the tracked points.

Each evaluation runs the Warp MPM (`pixie_gs.sim.run.simulate`) and returns the simulated
positions of the measured points (their Gaussians `ids`) at the measured times `t`, linearly
interpolated between simulated frames, in the splat's coordinates.

Batching: `predict_many` simulates several variants at once; on a GPU (or when asked) the
variants that share a grid go out as ONE batched simulation (sim/batch.py: one launch per kernel
and substep for all of them — each run is launch-bound alone), otherwise one after the other.
Batched and separate runs take the same substeps with the same arithmetic (tests/test_sim_batched.py).

CPU cost is the constraint, so large models are fitted on a REDUCED model — a random subset of
the Gaussians (always keeping the tracked ones) on a coarser grid — with a delta correction:
  prediction(θ) = full(θ₀) + [reduced(θ) − reduced(θ₀)]
where θ₀ is the current model. The reduced model only has to get the CHANGE an effect makes
right; the full model's own baseline (and its discretisation) is reused unchanged. Particle
volumes are cell volume shared by the particles in a cell (sim/run.py), so a subset keeps the
object's mass, and the coarse grid keeps the same physics at lower resolution.
"""
from __future__ import annotations

import copy
import hashlib
import json
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ComputationError, InputError
from ..progress import is_quiet, set_quiet
from ..splat import SplatCloud
from .measured import MeasuredTracks


@dataclass
class SimRecord:
    """One simulation a diagnosis made: a batch of runs, or one run alone (the timeline the
    benchmark prints: what ran when, and how long the host worked between simulations)."""

    stage: str          # the pipeline stage that asked for it (ForwardModel.stage)
    start_s: float      # time.perf_counter() at its start
    seconds: float      # wall time
    runs: int
    particles: int      # all runs together
    grid: int           # cells along the longest side
    frames: int
    stats: dict = field(default_factory=dict)  # batched: sim.batch.simulate_batch's `stats`

    @classmethod
    def since(cls, stage: str, start_s: float, runs: int, particles: int, grid: int, frames: int,
              stats: dict | None = None) -> "SimRecord":
        """The record of a simulation that began at `start_s` (time.perf_counter()) and ends now."""
        return cls(stage, start_s, time.perf_counter() - start_s, runs, particles, grid, frames, stats or {})


@dataclass
class Fidelity:
    """How to reduce a large model for fitting: at most `max_particles` Gaussians and a grid of
    `grid_scale` × the scene's cells (at least `min_grid`)."""

    max_particles: int = 3000
    grid_scale: float = 0.5
    min_grid: int = 24
    seed: int = 0


def sim_schedule(t: np.ndarray) -> tuple[int, float]:
    """(frames, fps) of a simulation from t = 0 that covers the measured times `t` (s)."""
    dt = float(np.median(np.diff(t)))
    fps = 1.0 / dt
    frames = int(np.ceil(t[-1] * fps - 1e-6)) + 1
    return max(frames, 2), fps


MAX_BATCH_RUNS = 64  # variants per batched simulation
MAX_BATCH_PARTICLES = 4_000_000  # particles per batched simulation (device memory ~ 200 B each)


def sample_at(xs: np.ndarray, fps: float, t: np.ndarray) -> np.ndarray:
    """Positions (T,M,3) at times `t` from frames `xs` (F,M,3) at t_i = i/fps (linear in time)."""
    u = np.clip(np.asarray(t) * fps, 0.0, len(xs) - 1.0)
    i0 = np.minimum(np.floor(u + 1e-9).astype(int), len(xs) - 1)
    i1 = np.minimum(i0 + 1, len(xs) - 1)
    w = (u - i0)[:, None, None]
    return (1.0 - w) * xs[i0] + w * xs[i1]


class ForwardModel:
    """Simulates model variants and returns the tracked points, counting runs and seconds."""

    def __init__(self, cloud: SplatCloud, tracks: MeasuredTracks, device: str = "auto",
                 fill: bool = False, fidelity: Fidelity | None = None, cache: dict | None = None,
                 batch: bool | None = None) -> None:
        """`cache` (optional, may be shared between diagnoses of the same model and tracked
        points) memoises simulated tracks by model variant, so repeated runs are free.
        `batch`: simulate the variants of one predict_many call as one batched simulation
        (None: on a GPU only — on the CPU, where Warp runs threads one after another, batching
        saves no kernel time)."""
        self.cloud = cloud
        self.tracks = tracks
        self.device = device
        if batch is None:
            from ..devices import resolve_warp_device

            batch = resolve_warp_device(device) != "cpu"
        self.batch = bool(batch)
        self.batches = 0  # batched simulations made (each counts its variants in `runs`)
        self.fill = fill
        self.frames, self.fps = sim_schedule(tracks.t)
        self.fidelity = fidelity or Fidelity()
        self.runs = 0
        self.seconds = 0.0
        self.stage = ""                          # label of the pipeline stage now running (for `log`)
        self.log: list[SimRecord] = []           # every simulation made, in order
        self.keep: np.ndarray | None = None      # Gaussians of the reduced model (None: not reduced)
        self.reduced_ids: np.ndarray | None = None
        self.grid_scale = 1.0
        if len(cloud) > self.fidelity.max_particles:
            self.keep, self.reduced_ids = reduced_subset(len(cloud), tracks.ids, self.fidelity)
            self.grid_scale = self.fidelity.grid_scale
        self._full_base: np.ndarray | None = None
        self._reduced_base: np.ndarray | None = None   # reduced run of θ₀ (made on first use)
        self._base_model: tuple | None = None          # θ₀ = (scene, cloud)
        self.cache = cache if cache is not None else {}
        self.cache_hits = 0
        self._context = _digest(tracks.ids, tracks.t, np.array([fill, self.frames, self.fps, len(cloud)]),
                                self.keep if self.keep is not None else np.zeros(0),
                                np.array([self.fidelity.max_particles, self.fidelity.grid_scale,
                                          self.fidelity.min_grid, self.fidelity.seed]))

    @property
    def is_reduced(self) -> bool:
        return self.keep is not None

    # ------------------------------------------------------------------ simulation
    def _key(self, cloud: SplatCloud, scene) -> tuple:
        return (self._context, len(cloud), json.dumps(scene.to_dict(), sort_keys=True), _cloud_digest(cloud))

    def prime(self, scene, cloud: SplatCloud, prediction: np.ndarray) -> None:
        """Store an already simulated full-model prediction (T,M,3) of (scene, cloud) in the cache."""
        self.cache[self._key(cloud, scene)] = np.asarray(prediction, np.float64)

    def _run(self, cloud: SplatCloud, scene, ids: np.ndarray) -> np.ndarray:
        result = self._run_many([(cloud, scene)], ids)[0]
        if isinstance(result, Exception):
            raise result
        return result

    def _run_many(self, variants: list[tuple[SplatCloud, object]], ids: np.ndarray) -> list:
        """Tracked points (T,M,3) per (cloud, scene), or the ComputationError of a diverged run
        (not cached); cached variants are not simulated again, duplicates only once."""
        keys = [self._key(cloud, scene) for cloud, scene in variants]
        todo: dict[tuple, tuple[SplatCloud, object]] = {}
        for key, variant in zip(keys, variants):
            if key in self.cache:
                self.cache_hits += 1
            elif key not in todo:
                todo[key] = variant
        results: dict[tuple, object] = {}
        if self.batch and todo:  # single runs too: every fitting run then has the same arithmetic
            results.update(self._simulate_batched(todo, ids))
        else:
            for key, (cloud, scene) in todo.items():
                try:
                    results[key] = self._simulate(cloud, scene, ids)
                except ComputationError as err:
                    results[key] = err
        for key, value in results.items():
            if not isinstance(value, Exception):
                self.cache[key] = value
        return [self.cache.get(key, results.get(key)) for key in keys]

    def _simulate_batched(self, todo: dict, ids: np.ndarray) -> dict:
        """Simulate the variants in `todo` in batches of runs sharing a grid (sim/batch.py)."""
        from ..sim.batch import batch_key, simulate_batch

        groups: dict[tuple, list[tuple]] = {}
        for key, (cloud, scene) in todo.items():
            groups.setdefault(batch_key(scene), []).append(key)
        out: dict = {}
        for keys in groups.values():
            chunk: list[tuple] = []
            size = 0
            for key in keys + [None]:
                n = 0 if key is None else len(todo[key][0])
                if chunk and (key is None or len(chunk) >= MAX_BATCH_RUNS or size + n > MAX_BATCH_PARTICLES):
                    start = time.perf_counter()
                    quiet = is_quiet()
                    set_quiet(True)
                    stats: dict = {}
                    try:
                        trajs = simulate_batch([todo[k] for k in chunk], self.frames, self.fps, device=self.device,
                                               fill=self.fill, points=ids, stats=stats)
                    finally:
                        set_quiet(quiet)
                        self.runs += len(chunk)
                        self.batches += 1
                        self._record(start, len(chunk), size, todo[chunk[0]][1], stats)
                    for k, traj in zip(chunk, trajs):
                        out[k] = traj if isinstance(traj, Exception) else \
                            sample_at(traj.x.astype(np.float64), self.fps, self.tracks.t)
                    chunk, size = [], 0
                if key is not None:
                    chunk.append(key)
                    size += n
        return out

    def _simulate(self, cloud: SplatCloud, scene, ids: np.ndarray) -> np.ndarray:
        from ..sim.run import simulate

        start = time.perf_counter()
        quiet = is_quiet()
        set_quiet(True)  # one bar per evaluation would flood the terminal; the fit shows its own
        try:
            traj = simulate(cloud, scene, self.frames, self.fps, device=self.device, fill=self.fill)
        finally:
            set_quiet(quiet)
            self.runs += 1
            self._record(start, 1, len(cloud), scene)
        return sample_at(traj.x[:, ids].astype(np.float64), self.fps, self.tracks.t)

    def _record(self, start: float, runs: int, particles: int, scene, stats: dict | None = None) -> None:
        record = SimRecord.since(self.stage, start, runs, particles, int(scene.domain.grid), self.frames, stats)
        self.seconds += record.seconds
        self.log.append(record)

    def simulate_full(self, scene, cloud: SplatCloud | None = None) -> np.ndarray:
        """Tracked points (T,M,3) of the full model `cloud` (default: the input) in `scene`."""
        return self._run(cloud if cloud is not None else self.cloud, scene, self.tracks.ids)

    def simulate_full_many(self, variants: list[tuple[object, SplatCloud]]) -> list:
        """simulate_full() of several (scene, cloud) variants at once (one batched simulation when
        `batch`; cached, so a later simulate_full of one of them is free): per variant the tracked
        points (T,M,3) or the ComputationError of a run that diverged."""
        return self._run_many([(cloud, scene) for scene, cloud in variants], self.tracks.ids)

    def _coarse(self, scene):
        coarse = copy.deepcopy(scene)
        coarse.domain.grid = min(scene.domain.grid,
                                 max(self.fidelity.min_grid, int(round(scene.domain.grid * self.grid_scale))))
        return coarse

    def _simulate_reduced_many(self, variants: list[tuple[object, SplatCloud]]) -> list:
        assert self.keep is not None and self.reduced_ids is not None
        subs = [cloud.subset(self.keep) for _, cloud in variants]
        if self.grid_scale < 1.0:
            try:
                return self._run_many([(sub, self._coarse(scene)) for sub, (scene, _) in zip(subs, variants)],
                                      self.reduced_ids)
            except InputError:
                # the coarse grid's wider boundary band may not fit the object: keep the scene's grid
                self.grid_scale = 1.0
                if self._reduced_base is not None:
                    raise RuntimeError("reduced grid changed after the baseline was set") from None
        return self._run_many([(sub, scene) for sub, (scene, _) in zip(subs, variants)], self.reduced_ids)

    def set_baseline(self, scene, cloud: SplatCloud | None = None,
                     full_prediction: np.ndarray | None = None) -> np.ndarray:
        """Make (scene, cloud) the current model θ₀; returns its full-model prediction.

        The reduced model's run of θ₀ is made only when a prediction needs it, in the same
        batched simulation as that prediction's variants: a baseline that is replaced before
        any prediction (the full-model polish sets several) costs no reduced run at all."""
        cloud = cloud if cloud is not None else self.cloud
        self._reduced_base = None
        self._full_base = full_prediction if full_prediction is not None else self.simulate_full(scene, cloud)
        self._base_model = (scene, cloud)
        return self._full_base

    def predict(self, scene, cloud: SplatCloud | None = None) -> np.ndarray:
        """Predicted tracked points (T,M,3) of a model variant (delta-corrected when reduced)."""
        result = self.predict_many([(scene, cloud)])[0]
        if isinstance(result, Exception):
            raise result
        return result

    def predict_many(self, variants: list[tuple[object, SplatCloud | None]]) -> list:
        """predict() for several (scene, cloud) variants at once (batched when `batch`): per
        variant the tracked points (T,M,3), or the ComputationError of a run that diverged."""
        variants = [(scene, cloud if cloud is not None else self.cloud) for scene, cloud in variants]
        if not self.is_reduced:
            return self._run_many([(cloud, scene) for scene, cloud in variants], self.tracks.ids)
        if self._full_base is None or self._base_model is None:
            raise RuntimeError("call set_baseline() before predict()")
        with_base = self._reduced_base is None
        results = self._simulate_reduced_many(([self._base_model] if with_base else []) + variants)
        if with_base:
            base = results.pop(0)
            if isinstance(base, Exception):
                raise base
            self._reduced_base = base
        return [r if isinstance(r, Exception) else self._full_base + (r - self._reduced_base) for r in results]


def reduced_subset(n: int, ids: np.ndarray, fidelity: Fidelity) -> tuple[np.ndarray, np.ndarray]:
    """(kept Gaussian indices (sorted), positions of the tracked `ids` within them)."""
    rng = np.random.default_rng(fidelity.seed)
    tracked = np.unique(ids)
    others = np.setdiff1d(np.arange(n), tracked)
    extra = min(max(fidelity.max_particles - len(tracked), 0), len(others))
    keep = np.sort(np.concatenate([tracked, rng.choice(others, extra, replace=False)]))
    return keep, np.searchsorted(keep, ids)


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _cloud_digest(cloud: SplatCloud) -> str:
    """Digest of what the simulation reads from a cloud (positions and material attributes)."""
    names = [n for n in ("material_id", "E", "nu", "density", "part_id") if cloud.has(n)]
    return _digest(cloud.means, *[cloud.get(n) for n in names])
