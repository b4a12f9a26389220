"""Measured tracks: load, validate and align them to the splat's Gaussians.

A measured `.npz` (the same keys as `pixie simulate`'s tracks.npz) holds
  t        (T,)   seconds, strictly increasing, >= 0 (time since the simulation starts)
  x        (T,M,3) positions of M tracked points in the splat's coordinates
  ids      (M,)   optional: index of the Gaussian each point follows; otherwise each point is
                  matched to the nearest Gaussian centre at its first visible frame
  visible  (T,M)  optional bool: False where the tracker lost the point (x may be NaN there)
Tracks may be a sparse, noisy subset of the Gaussians, as a point tracker on video gives.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, require_file
from ..splat import SplatCloud

MIN_TRACKED_POINTS = 10
MIN_FRAMES = 3


@dataclass
class MeasuredTracks:
    """Validated measured tracks aligned to Gaussians of one splat.

    `t` (T,) s; `x` (T,M,3) in the splat's coordinates (NaN where not visible);
    `visible` (T,M) bool; `ids` (M,) Gaussian index each point follows;
    `match_distance` (M,) distance (splat units) of the nearest-neighbour match (0 for given ids).
    """

    t: np.ndarray
    x: np.ndarray
    visible: np.ndarray
    ids: np.ndarray
    match_distance: np.ndarray
    source: str | None = None

    @property
    def num_frames(self) -> int:
        return len(self.t)

    @property
    def num_points(self) -> int:
        return self.x.shape[1]

    @property
    def num_observations(self) -> int:
        """Number of observed scalar coordinates (3 per visible point per frame)."""
        return int(self.visible.sum()) * 3

    def subset_points(self, index: np.ndarray) -> "MeasuredTracks":
        return MeasuredTracks(self.t, self.x[:, index], self.visible[:, index], self.ids[index],
                              self.match_distance[index], self.source)


MAX_SIM_FRAMES = 100_000  # simulation frames a diagnosis may need to cover the measured times
MIN_FRAME_INTERVAL_S = 1e-5
MAX_FRAME_INTERVAL_S = 1e3


def check_track_sizes(t: np.ndarray, num_points: int, src: str) -> None:
    """InputError before any work when the tracks have no points, a frame interval too small, or
    times so long that covering them would take an absurd number of simulation frames."""
    if num_points == 0:
        raise InputError("'x' holds zero tracked points", src)
    dt = float(np.median(np.diff(t)))
    if not MIN_FRAME_INTERVAL_S <= dt <= MAX_FRAME_INTERVAL_S:
        raise InputError(f"median frame interval {dt:g} s is outside {MIN_FRAME_INTERVAL_S:g}..{MAX_FRAME_INTERVAL_S:g} s",
                         src)
    frames = t[-1] / dt + 1
    if frames > MAX_SIM_FRAMES:
        raise InputError(f"'t' runs to {t[-1]:g} s at {dt:g} s per frame: {frames:.3g} simulation frames "
                         f"would be needed (at most {MAX_SIM_FRAMES})", src)


def validate_arrays(t: np.ndarray, x: np.ndarray, visible: np.ndarray | None, ids: np.ndarray | None,
                    num_gaussians: int, source: str | Path | None = None) -> tuple:
    """Check shapes/values of measured arrays; return (t float64, x float64, visible bool, ids|None).

    Raises InputError naming `source` and the problem for every malformed input.
    """
    src = str(source) if source is not None else "<measured>"
    t = np.asarray(t)
    x = np.asarray(x)
    if t.ndim != 1:
        raise InputError(f"'t' must have shape (T,), got {t.shape}", src)
    if x.ndim != 3 or x.shape[2] != 3:
        raise InputError(f"'x' must have shape (T,M,3), got {x.shape}", src)
    if x.shape[0] != len(t):
        raise InputError(f"'t' has {len(t)} frames but 'x' has {x.shape[0]}", src)
    if not np.issubdtype(t.dtype, np.number) or not np.issubdtype(x.dtype, np.number):
        raise InputError("'t' and 'x' must be numeric arrays", src)
    t = t.astype(np.float64)
    x = x.astype(np.float64)
    if len(t) < MIN_FRAMES:
        raise InputError(f"only {len(t)} frames; at least {MIN_FRAMES} are needed", src)
    if not np.isfinite(t).all():
        raise InputError("'t' contains NaN or inf", src)
    if np.any(np.diff(t) <= 0):
        bad = int(np.argmax(np.diff(t) <= 0))
        raise InputError(f"'t' is not strictly increasing (t[{bad}]={t[bad]:g} s, "
                         f"t[{bad + 1}]={t[bad + 1]:g} s)", src)
    if t[0] < 0:
        raise InputError(f"'t' starts at {t[0]:g} s; times are seconds since the simulation starts (>= 0)", src)
    check_track_sizes(t, x.shape[1], src)
    T, M = x.shape[:2]
    if visible is None:
        vis = np.ones((T, M), bool)
    else:
        vis = np.asarray(visible)
        if vis.shape != (T, M):
            raise InputError(f"'visible' must have shape (T,M)=({T},{M}), got {vis.shape}", src)
        vis = vis.astype(bool)
    finite = np.isfinite(x).all(axis=2)
    nan_visible = ~finite & vis
    if nan_visible.any():
        f, m = (int(v[0]) for v in np.nonzero(nan_visible))
        count = int(nan_visible.sum())
        raise InputError(f"'x' has {count} NaN/inf positions where the point is visible "
                         f"(first: frame {f}, point {m}); mark them False in 'visible'", src)
    if ids is not None:
        ids = np.asarray(ids)
        if ids.shape != (M,):
            raise InputError(f"'ids' must have shape (M,)=({M},), got {ids.shape}", src)
        if not np.issubdtype(ids.dtype, np.integer):
            raise InputError(f"'ids' must be integers, got {ids.dtype}", src)
        if ids.size and (ids.min() < 0 or ids.max() >= num_gaussians):
            raise InputError(f"'ids' out of range [0, {num_gaussians}) for the splat "
                             f"(min {ids.min()}, max {ids.max()})", src)
        if len(np.unique(ids)) != len(ids):
            raise InputError("'ids' contains duplicates; each tracked point must follow its own Gaussian", src)
        ids = ids.astype(np.int64)
    usable = vis.sum(axis=0) >= 2
    if int(usable.sum()) < MIN_TRACKED_POINTS:
        raise InputError(f"only {int(usable.sum())} points are visible in at least 2 frames; "
                         f"at least {MIN_TRACKED_POINTS} tracked points are needed", src)
    return t, x, vis, ids


def match_to_gaussians(x: np.ndarray, visible: np.ndarray, means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest Gaussian centre to each point at its first visible frame → (ids (M,), distances (M,)).

    Assumes the object is still at its rest (input) pose when each point is first seen, as it is
    when tracking starts at t0. Points are matched one-to-one greedily by distance.
    """
    from ..knn import knn

    first = np.argmax(visible, axis=0)
    p0 = x[first, np.arange(x.shape[1])]
    k = min(8, len(means))
    dist, idx = knn(means, p0, k=k)
    ids = np.full(len(p0), -1, np.int64)
    out_d = np.zeros(len(p0))
    taken: set[int] = set()
    for m in np.argsort(dist[:, 0]):
        for j in range(k):
            if int(idx[m, j]) not in taken:
                ids[m], out_d[m] = idx[m, j], dist[m, j]
                taken.add(int(idx[m, j]))
                break
        else:  # all k nearest taken: accept a shared Gaussian rather than fail
            ids[m], out_d[m] = idx[m, 0], dist[m, 0]
    return ids, out_d


def load_measured(path: str | Path, cloud: SplatCloud) -> MeasuredTracks:
    """Read and validate a measured `.npz`, aligning its points to `cloud`'s Gaussians."""
    path = require_file(path, "a .npz file")
    with open(path, "rb") as fh:
        if fh.read(4) != b"PK\x03\x04":
            raise InputError("not a .npz archive (expected NumPy arrays t (T,) and x (T,M,3))", path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as exc:  # zip/format errors from numpy
        raise InputError(f"cannot read as .npz ({type(exc).__name__}: {exc})", path) from None
    for key in ("t", "x"):
        if key not in arrays:
            raise InputError(f"missing array '{key}' (a measured .npz needs t (T,) and x (T,M,3))", path)
    return tracks_from_arrays(arrays["t"], arrays["x"], cloud, arrays.get("visible"), arrays.get("ids"), path)


def tracks_from_arrays(t: np.ndarray, x: np.ndarray, cloud: SplatCloud, visible: np.ndarray | None = None,
                       ids: np.ndarray | None = None, source: str | Path | None = None) -> MeasuredTracks:
    """Validated MeasuredTracks from in-memory arrays (see `load_measured`)."""
    t, x, vis, ids = validate_arrays(t, x, visible, ids, len(cloud), source)
    x = np.where(vis[:, :, None], x, np.nan)
    if ids is None:
        ids, dist = match_to_gaussians(x, vis, cloud.means.astype(np.float64))
    else:
        dist = np.zeros(len(ids))
    keep = vis.sum(axis=0) >= 2
    tracks = MeasuredTracks(t, x, vis, ids, dist, None if source is None else str(source))
    return tracks if keep.all() else tracks.subset_points(np.nonzero(keep)[0])


def save_measured(path: str | Path, t: np.ndarray, x: np.ndarray, ids: np.ndarray | None = None,
                  visible: np.ndarray | None = None) -> None:
    """Write a measured-tracks `.npz` atomically (used by the example and benchmarks)."""
    from ..atomic import atomic_path

    arrays = {"t": np.asarray(t, np.float64), "x": np.asarray(x, np.float32)}
    if ids is not None:
        arrays["ids"] = np.asarray(ids, np.int64)
    if visible is not None:
        arrays["visible"] = np.asarray(visible, bool)
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
