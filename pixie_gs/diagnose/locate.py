"""Locate the disagreement between simulated and measured tracks in space and time.

Residuals r = measured − simulated (T,M,3), in the splat's coordinates. "Where": RMS per part
(`part_id`), per material and per spatial k-means cluster of the rest positions; "when": the
per-frame RMS curve, the first frame whose residual clearly exceeds the tracking-noise floor
(the onset), and the frames where it rises fastest.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..materials import MATERIAL_NAMES
from ..splat import SplatCloud


def residuals(measured_x: np.ndarray, simulated_x: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """measured − simulated (T,M,3), zero where the point is not visible (so sums skip it)."""
    r = np.asarray(measured_x, np.float64) - np.asarray(simulated_x, np.float64)
    return np.where(visible[:, :, None], np.nan_to_num(r), 0.0)


def sum_squares(r: np.ndarray) -> float:
    """Sum of squared residual coordinates (units²)."""
    return float(np.sum(np.square(r)))


def rms_gap(r: np.ndarray, visible: np.ndarray) -> float:
    """RMS point distance between measured and simulated over visible (frame, point) pairs."""
    n = max(int(visible.sum()), 1)
    return float(np.sqrt(np.sum(np.square(r)) / n))


def per_frame_rms(r: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """(T,) RMS point distance of each frame (0 where nothing is visible)."""
    n = np.maximum(visible.sum(axis=1), 1)
    return np.sqrt(np.square(r).sum(axis=(1, 2)) / n)


def per_point_rms(r: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """(M,) RMS distance of each tracked point over the frames where it is visible."""
    n = np.maximum(visible.sum(axis=0), 1)
    return np.sqrt(np.square(r).sum(axis=(0, 2)) / n)


def noise_sigma(r: np.ndarray, visible: np.ndarray) -> float:
    """Per-coordinate tracking-noise σ estimated from the residual's second time differences.

    A missing physical effect makes a residual that is smooth in time; white tracking noise is
    not. For white noise of σ, (r[t+1] − 2r[t] + r[t−1]) has variance 6σ²; the median absolute
    deviation (÷0.6745) makes the estimate robust to the few frames with impacts.
    """
    if r.shape[0] < 3:
        return 0.0
    ok = visible[2:] & visible[1:-1] & visible[:-2]
    d2 = (r[2:] - 2 * r[1:-1] + r[:-2])[ok]
    if d2.size == 0:
        return 0.0
    mad = np.median(np.abs(d2 - np.median(d2)))
    return float(mad / 0.6745 / np.sqrt(6.0))


def spatial_clusters(rest_positions: np.ndarray, k: int = 4, seed: int = 0) -> np.ndarray:
    """k-means labels (M,) of the tracked points' rest positions (k-means++ seeds, deterministic
    for `seed`, without importing scipy: kmeans.py); fewer than k clusters when there are fewer
    distinct positions, numbered by their centres' coordinates."""
    from ..kmeans import kmeans_pp

    k = int(max(1, min(k, len(rest_positions))))
    if k == 1:
        return np.zeros(len(rest_positions), np.int64)
    _, labels = kmeans_pp(np.asarray(rest_positions, np.float64), k, seed=seed)
    return labels.astype(np.int64)


@dataclass
class RegionGap:
    """RMS gap of one region of tracked points (a part, a material or a spatial cluster)."""

    kind: str          # "part", "material" or "cluster"
    key: int           # part_id, material id or cluster index
    name: str
    num_points: int
    rms: float

    def to_dict(self) -> dict:
        return {"kind": self.kind, "key": self.key, "name": self.name, "num_points": self.num_points,
                "rms": self.rms}


@dataclass
class Location:
    """Where and when the model disagrees with the measurement."""

    rms: float                       # overall RMS point distance (splat units)
    noise_sigma: float               # per-coordinate tracking noise estimate (splat units)
    frame_rms: np.ndarray            # (T,)
    point_rms: np.ndarray            # (M,)
    regions: list[RegionGap] = field(default_factory=list)
    onset_frame: int | None = None   # first frame whose RMS clearly exceeds the noise floor
    rising_frames: list[int] = field(default_factory=list)  # frames where the RMS rises fastest

    def worst(self, kind: str) -> RegionGap | None:
        cands = [g for g in self.regions if g.kind == kind]
        return max(cands, key=lambda g: g.rms) if cands else None

    def ranked_parts(self) -> list[int]:
        """part_ids ordered from the worst (largest RMS gap) to the best."""
        return [g.key for g in sorted((g for g in self.regions if g.kind == "part"), key=lambda g: -g.rms)]

    def summary(self, t: np.ndarray) -> dict:
        worst = {k: (self.worst(k).to_dict() if self.worst(k) else None) for k in ("part", "material", "cluster")}
        return {
            "rms": self.rms,
            "noise_sigma": self.noise_sigma,
            "onset_s": None if self.onset_frame is None else float(t[self.onset_frame]),
            "rising_s": [float(t[f]) for f in self.rising_frames],
            "worst": worst,
            "regions": [g.to_dict() for g in self.regions],
        }


def region_gaps(r: np.ndarray, visible: np.ndarray, labels: np.ndarray, kind: str,
                names: dict[int, str] | None = None) -> list[RegionGap]:
    """RMS gap per label value (one RegionGap per distinct label)."""
    out = []
    for key in np.unique(labels):
        sel = labels == key
        n = max(int(visible[:, sel].sum()), 1)
        rms = float(np.sqrt(np.square(r[:, sel]).sum() / n))
        name = (names or {}).get(int(key), f"{kind} {int(key)}")
        out.append(RegionGap(kind, int(key), name, int(sel.sum()), rms))
    return out


def locate(r: np.ndarray, visible: np.ndarray, cloud: SplatCloud, ids: np.ndarray,
           num_clusters: int = 4, sigma: float | None = None) -> Location:
    """Where (part / material / spatial cluster) and when (onset, rising frames) the gap lies."""
    sigma = noise_sigma(r, visible) if sigma is None else sigma
    frame = per_frame_rms(r, visible)
    point = per_point_rms(r, visible)
    regions: list[RegionGap] = []
    if cloud.has("part_id"):
        regions += region_gaps(r, visible, cloud.get("part_id")[ids], "part")
    if cloud.has("material_id"):
        regions += region_gaps(r, visible, cloud.get("material_id")[ids], "material",
                               {k: v for k, v in MATERIAL_NAMES.items()})
    rest = cloud.means[ids].astype(np.float64)
    regions += region_gaps(r, visible, spatial_clusters(rest, num_clusters), "cluster")
    # pure noise gives a frame mean-square of 3σ² with relative spread sqrt(2/(3M)) over M
    # visible points; the gap is real where a frame exceeds that by 4 spreads
    m = np.maximum(visible.sum(axis=1), 1)
    floor = np.sqrt(3.0 * sigma ** 2 * (1.0 + 4.0 * np.sqrt(2.0 / (3.0 * m))))
    above = np.nonzero(frame > np.maximum(floor, 1e-12))[0]
    onset = int(above[0]) if len(above) else None
    rise = np.diff(frame)
    rising = [int(i + 1) for i in np.argsort(-rise)[:3] if rise[i] > 0] if len(rise) else []
    return Location(float(np.sqrt(np.square(r).sum() / max(int(visible.sum()), 1))), sigma, frame, point,
                    regions, onset, sorted(rising))
