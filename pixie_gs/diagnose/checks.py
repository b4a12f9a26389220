"""Registration and sanity checks of measured tracks BEFORE any physics is fitted.

Real tracks (from video) come in the tracker's units and frame, with a clock that may not start
at the release, and with tracks that slipped off the object. Fitting physics to such data names
the wrong effect with confidence, so `pixie diagnose` first
  * compares the measured extent with the model's (units: millimetres are refused with a clear
    message unless `--units mm` says so);
  * fits a rigid registration at t₀ (iterative closest point, Kabsch) and applies it when it
    moves the points by more than half a Gaussian spacing;
  * checks the match distances against the Gaussian spacing;
  * after the first simulation: fits a start-time offset on the early frames, and finds
    outlier tracks with a robust (Huber) score of how far each track's residual departs from
    its neighbours' on the same part (a missing physical effect moves neighbours alike; a
    slipped track does not); outliers are listed and left out.
All lengths are in the splat's units (the tracks' after `--units`), times in seconds.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..knn import CellGrid, knn
from ..splat import SplatCloud
from .measured import MeasuredTracks, match_to_gaussians

UNIT_FACTORS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}   # measured coordinate × factor = splat units
MAX_EXTENT_RATIO = 3.0        # tracks wider than 3× the model cannot be a subset of its points
MIN_EXTENT_RATIO = 0.02       # tracks 50× smaller than the model: other units
MAX_MATCH_SPACINGS = 3.0      # median match distance allowed, in Gaussian spacings
OUTLIER_Z = 5.0               # robust z-score above which a track is an outlier (clean tracks: below 1.9
                              # against the independent truth, up to 4.3 against this solver's baseline)
HUBER_C = 1.345               # Huber constant (95 % efficiency for Gaussian data)


@dataclass
class Registration:
    """What the checks found and changed (reported in report.json and the JSON summary)."""

    units_factor: float = 1.0
    extent_ratio: float = 1.0             # measured / model extent at t₀ (after units)
    gaussian_spacing: float = 0.0         # median nearest-neighbour distance of the Gaussians
    match_median: float = 0.0             # median match distance (after registration)
    rotation_deg: float = 0.0             # fitted rigid registration at t₀
    translation: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    registration_applied: bool = False
    time_offset_s: float = 0.0            # fitted: simulation time = measured time − offset
    time_offset_applied: bool = False
    outliers: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"units_factor": self.units_factor, "extent_ratio": self.extent_ratio,
                "gaussian_spacing": self.gaussian_spacing, "match_median": self.match_median,
                "rotation_deg": self.rotation_deg, "translation": self.translation,
                "registration_applied": self.registration_applied, "time_offset_s": self.time_offset_s,
                "time_offset_applied": self.time_offset_applied, "outliers": self.outliers,
                "warnings": self.warnings}


def _first_positions(tracks: MeasuredTracks) -> np.ndarray:
    first = np.argmax(tracks.visible, axis=0)
    return tracks.x[first, np.arange(tracks.num_points)]


def _extent(p: np.ndarray) -> float:
    return float(np.max(np.ptp(p, axis=0)))


def gaussian_spacing(means: np.ndarray) -> float:
    """Median distance from a Gaussian centre to its nearest neighbour (splat units)."""
    if len(means) < 2:
        return 0.0
    d, _ = knn(means, means, k=2)
    return float(np.median(d[:, 1]))


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Proper rotation R and translation t minimising Σ|R·src + t − dst|²."""
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cd - R @ cs


def icp(points: np.ndarray, means: np.ndarray, iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Rigid transform taking `points` onto the Gaussian centres (point-to-point ICP)."""
    grid = CellGrid(means)
    R, t = np.eye(3), means.mean(0) - points.mean(0)
    for _ in range(iterations):
        moved = points @ R.T + t
        d, idx = grid.query(moved, k=1)
        d, idx = d[:, 0], idx[:, 0]
        keep = d <= np.percentile(d, 90) + 1e-12   # trim the worst 10 % (outliers, partial views)
        R_new, t_new = kabsch(points[keep], means[idx[keep]])
        if np.allclose(R_new, R, atol=1e-7) and np.allclose(t_new, t, atol=1e-9):
            break
        R, t = R_new, t_new
    return R, t


def _with_x(tracks: MeasuredTracks, x: np.ndarray, cloud: SplatCloud, rematch: bool) -> MeasuredTracks:
    x = np.where(tracks.visible[:, :, None], x, np.nan)
    if rematch:
        ids, dist = match_to_gaussians(x, tracks.visible, cloud.means.astype(np.float64))
    else:
        ids, dist = tracks.ids, tracks.match_distance
    return MeasuredTracks(tracks.t, x, tracks.visible, ids, dist, tracks.source)


def check_geometry(tracks: MeasuredTracks, cloud: SplatCloud, units: str | None = None
                   ) -> tuple[MeasuredTracks, Registration]:
    """Units, rigid registration at t₀ and match distances → (tracks in splat units, report).

    Raises InputError (naming the measured file) when the tracks' extent does not fit the model's
    (e.g. millimetres against a model in metres) and no `units` was given, or when the tracked
    points at t₀ lie far from every Gaussian even after registration.
    """
    src = tracks.source or "<measured>"
    reg = Registration()
    matched = bool(np.any(tracks.match_distance > 0))   # ids were matched by us, not given
    means = cloud.means.astype(np.float64)
    model_extent = _extent(means)
    if units is not None:
        if units not in UNIT_FACTORS:
            raise InputError(f"--units must be one of {', '.join(UNIT_FACTORS)}, got '{units}'")
        reg.units_factor = UNIT_FACTORS[units]
        if reg.units_factor != 1.0:
            tracks = _with_x(tracks, tracks.x * reg.units_factor, cloud, matched)
    p0 = _first_positions(tracks)
    ratio = _extent(p0) / max(model_extent, 1e-30)
    reg.extent_ratio = float(ratio)
    if not (MIN_EXTENT_RATIO <= ratio <= MAX_EXTENT_RATIO):
        guess = next((u for u, f in UNIT_FACTORS.items() if f != 1.0 and 0.3 <= ratio * f <= MAX_EXTENT_RATIO), None)
        hint = f"; they look like {guess}: pass --units {guess}" if guess and units is None else \
            "; convert them to the splat's coordinates (or pass --units mm|cm|m)"
        raise InputError(f"tracked points span {_extent(p0):.4g} units at t0 but the model spans "
                         f"{model_extent:.4g} (×{ratio:.3g}): the tracks are not in the splat's units{hint}", src)
    reg.gaussian_spacing = gaussian_spacing(means)
    # rigid registration at t₀: applied when it moves the tracked points noticeably
    R, t = icp(p0, means)
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))
    reg.rotation_deg, reg.translation = angle, [float(v) for v in t]
    shift = np.sqrt(np.mean(np.sum((p0 @ R.T + t - p0) ** 2, axis=1)))
    if matched and shift > 0.5 * reg.gaussian_spacing:
        before = float(np.median(tracks.match_distance))
        moved = _with_x(tracks, np.einsum("ij,tmj->tmi", R, tracks.x) + t, cloud, True)
        if float(np.median(moved.match_distance)) < 0.8 * before:
            tracks = moved
            reg.registration_applied = True
            reg.warnings.append(f"tracks registered rigidly onto the model at t0: rotation {angle:.2f}°, "
                                f"translation {np.round(t, 4).tolist()} (splat units)")
    reg.match_median = float(np.median(tracks.match_distance)) if matched else 0.0
    if matched and reg.match_median > MAX_MATCH_SPACINGS * reg.gaussian_spacing:
        raise InputError(f"tracked points at t0 lie {reg.match_median:.3g} (median) from the nearest Gaussian, "
                         f"{reg.match_median / reg.gaussian_spacing:.1f}× the Gaussian spacing "
                         f"{reg.gaussian_spacing:.3g}: they are not at the model's rest pose or in its "
                         "coordinates", src)
    return tracks, reg


def huber_weights(z: np.ndarray, c: float = HUBER_C) -> np.ndarray:
    """Huber weights min(1, c/|z|) of robust z-scores (1 for inliers, → 0 for gross outliers)."""
    az = np.abs(z)
    return np.where(az <= c, 1.0, c / np.maximum(az, 1e-300))


def outlier_tracks(r: np.ndarray, visible: np.ndarray, rest: np.ndarray, part: np.ndarray,
                   sigma: float, k: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Tracks whose residual departs from their neighbours' → (outlier mask (M,), robust z (M,)).

    For every track, the residual curve r_m(t) (measured − simulated) is compared with the
    per-frame median residual of its k nearest tracked neighbours on the same part (rest
    positions): d_m = RMS_t |r_m − median_nbrs r|. A missing physical effect moves
    neighbouring points alike, so d is small for all tracks; a tracker that slipped or got stuck
    gives one large d. z = (d − median d) / (1.4826 MAD d), floored by the tracking noise; a
    track with z > OUTLIER_Z (Huber weight < 0.27) is an outlier.
    """
    d = outlier_distances(r, visible, rest, part, k)
    med = float(np.median(d))
    mad = float(np.median(np.abs(d - med))) * 1.4826
    scale = max(mad, 3.0 * sigma, 1e-12)
    z = (d - med) / scale
    return z > OUTLIER_Z, z


def outlier_distances(r: np.ndarray, visible: np.ndarray, rest: np.ndarray, part: np.ndarray,
                      k: int = 6) -> np.ndarray:
    """d_m = RMS over frames of |r_m − per-frame median of its k nearest tracked neighbours on
    the same part| (M,), 0 where a part has < 3 tracks or a track < 2 usable frames; all tracks
    at once (outlier_distances_reference is the per-track loop it replaces)."""
    M = r.shape[1]
    d = np.zeros(M)
    for p in np.unique(part):
        idx = np.nonzero(part == p)[0]
        if len(idx) < 3:
            continue
        kk = min(k + 1, len(idx))
        _, nb = knn(rest[idx], rest[idx], k=kk)
        others = idx[nb[:, 1:]]                                           # (n, k) neighbours per track
        ref = _nan_median(np.where(visible[:, others, None], r[:, others], np.nan), axis=2)   # (T, n, 3)
        ok = visible[:, idx] & np.isfinite(ref).all(axis=2)              # (T, n)
        sq = np.where(ok, np.sum((np.nan_to_num(r[:, idx]) - np.nan_to_num(ref)) ** 2, axis=2), 0.0)
        count = ok.sum(axis=0)
        use = count >= 2
        d[idx[use]] = np.sqrt(sq.sum(axis=0)[use] / count[use])
    return d


def outlier_distances_reference(r: np.ndarray, visible: np.ndarray, rest: np.ndarray, part: np.ndarray,
                                k: int = 6) -> np.ndarray:
    """Plain reference of outlier_distances: one track at a time, brute-force neighbours, np.nanmedian."""
    from ..knn import knn_brute

    d = np.zeros(r.shape[1])
    for p in np.unique(part):
        idx = np.nonzero(part == p)[0]
        if len(idx) < 3:
            continue
        _, nb = knn_brute(rest[idx], rest[idx], min(k + 1, len(idx)))
        for j, m in enumerate(idx):
            others = idx[nb[j, 1:]]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a frame no neighbour saw → NaN, as intended
                ref = np.nanmedian(np.where(visible[:, others, None], r[:, others], np.nan), axis=1)
            ok = visible[:, m] & np.isfinite(ref).all(axis=1)
            if ok.sum() >= 2:
                d[m] = float(np.sqrt(np.mean(np.sum((r[ok, m] - ref[ok]) ** 2, axis=1))))
    return d


def _nan_median(a: np.ndarray, axis: int) -> np.ndarray:
    """np.nanmedian along `axis` for short axes (a few neighbours), by sorting: NaN sorts last."""
    a = np.sort(a, axis=axis)
    n = np.sum(~np.isnan(a), axis=axis, keepdims=True)
    lo = np.take_along_axis(a, np.maximum((n - 1) // 2, 0), axis=axis)
    hi = np.take_along_axis(a, np.minimum(n // 2, a.shape[axis] - 1), axis=axis)
    return np.squeeze(np.where(n > 0, 0.5 * (lo + hi), np.nan), axis=axis)


def fit_time_offset(frames: np.ndarray, fps: float, x: np.ndarray, visible: np.ndarray, t: np.ndarray,
                    max_frames: float = 3.0, window: int | None = None) -> tuple[float, float, float]:
    """Start-time offset δ (s) with simulation time = t − δ, fitted on the early frames.

    `frames` (F,M,3) simulated tracked points at i/fps; only the first `window` measured frames
    (default: the first third, at least 4) are used, where a missing effect has had little time
    to act, and the loss is Huber (robust to a few bad points). Returns (δ, loss(δ), loss(0)).
    """
    from .forward import sample_at

    T = len(t)
    w = window or max(4, T // 3)
    sel = slice(0, min(w, T))
    vis = visible[sel]

    def errors(delta: float) -> np.ndarray:
        pred = sample_at(frames, fps, np.asarray(t[sel]) - delta)
        r = np.where(vis[:, :, None], np.nan_to_num(x[sel] - pred), 0.0)
        return np.sqrt(np.sum(r ** 2, axis=2))[vis]

    c = HUBER_C * max(float(np.median(errors(0.0))), 1e-12)  # one robust scale for every shift

    def loss(delta: float) -> float:
        e = errors(delta)
        return float(np.sum(np.where(e <= c, 0.5 * e ** 2, c * (e - 0.5 * c))))

    grid = np.arange(-max_frames, max_frames + 1e-9, 0.25) / fps
    losses = np.array([loss(float(g)) for g in grid])
    i = int(np.argmin(losses))
    best = float(grid[i])
    if 0 < i < len(grid) - 1:  # parabolic refinement between grid points
        a, b, c = losses[i - 1], losses[i], losses[i + 1]
        den = a - 2 * b + c
        if den > 0:
            best = float(grid[i] + 0.5 * (a - c) / den * (grid[1] - grid[0]))
    return best, loss(best), loss(0.0)
