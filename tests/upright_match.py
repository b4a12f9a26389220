"""Symmetry-aware up error, decided by geometry alone (not by the code under test).

Shared by tests/test_prepare_upright.py and benchmarks/bench_prepare.py. An estimated up is as good
as the true one when the object, put upright by the estimate, is the same point set (positions and
part labels) as the object put upright by the truth, up to a turn about the vertical: a ball, a
cube or a round fruit rests the same on any side. The two sets are compared by the symmetric mean
Chamfer distance (nearest neighbour with the same part label), minimised over the turn about the
vertical (10° steps one way, then 1° both ways), and the 95th percentile of the nearest-neighbour
distances at that turn, against the objects' own Gaussian spacing (median nearest-neighbour
distance): a perfect symmetry gives about one spacing (two at the 95th percentile), since the
turned Gaussians fall between the original ones.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

MATCH_SPACINGS = 1.5  # mean Chamfer ≤ this × the Gaussian spacing …
MATCH_P95_SPACINGS = 2.4  # … and its 95th percentile ≤ this: the same shape (exact symmetries of a sphere,
# a cube, the generated balls measure ≤ 1.2 and ≤ 2.25; a filled duck tilted 11° 1.3–1.5 and 2.5–3.0)
POINTS = 2000


def _upright(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """points (N,3) turned so `up` becomes +z (scipy's align_vectors), centred on their mean."""
    rot, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [np.asarray(up, np.float64) / np.linalg.norm(up)])
    c = points - points.mean(axis=0)
    return rot.apply(c)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two directions (degrees)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def chamfer_over_spacing(points: np.ndarray, labels: np.ndarray, est_up: np.ndarray, true_up: np.ndarray,
                         seed: int = 0) -> tuple[float, float]:
    """(smallest symmetric mean Chamfer distance over turns about the vertical, 95th percentile of
    the nearest-neighbour distances at that turn) between the object put upright by `est_up` and
    by `true_up`, both divided by the Gaussian spacing. points (N,3), labels (N,) part ids. A
    sample of POINTS Gaussians of each is matched against all of the other, so the spacing is the
    full cloud's. The percentile catches filled objects, whose interior matches whatever the tilt."""
    rng = np.random.default_rng(seed)
    p = np.asarray(points, np.float64)
    lab = np.asarray(labels, np.float64)
    pick = rng.choice(len(p), POINTS, replace=False) if len(p) > POINTS else np.arange(len(p))
    a, b = _upright(p, est_up), _upright(p, true_up)
    far = 100.0 * float(np.ptp(b, axis=0).max() + 1.0)  # label as a 4th coordinate: never matched across parts
    tree_a = cKDTree(np.column_stack([a, lab * far]))
    tree_b = cKDTree(np.column_stack([b, lab * far]))
    spacing = float(np.median(tree_b.query(np.column_stack([b[pick], lab[pick] * far]), k=2)[0][:, 1]))
    a_s, b_s, l_s = a[pick], b[pick], lab[pick] * far

    def dists(theta: float, both: bool = True) -> np.ndarray:
        c, s = np.cos(theta), np.sin(theta)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        d1 = tree_b.query(np.column_stack([a_s @ rz.T, l_s]))[0]
        return np.concatenate([d1, tree_a.query(np.column_stack([b_s @ rz, l_s]))[0]]) if both else d1

    coarse = np.radians(np.arange(0.0, 360.0, 10.0))
    best = coarse[int(np.argmin([dists(t, both=False).mean() for t in coarse]))]
    d = min((dists(t) for t in best + np.radians(np.arange(-6.0, 6.01, 1.0))), key=lambda v: float(v.mean()))
    scale = max(spacing, 1e-12)
    return float(d.mean()) / scale, float(np.percentile(d, 95)) / scale


def symmetric_error(points: np.ndarray, labels: np.ndarray, est_up: np.ndarray, true_up: np.ndarray
                    ) -> tuple[float, bool]:
    """(error in degrees counting a symmetric equivalent as 0, whether it was counted that way)."""
    raw = angle_deg(est_up, true_up)
    if raw <= 1.0:
        return raw, False
    mean, p95 = chamfer_over_spacing(points, labels, est_up, true_up)
    same = mean <= MATCH_SPACINGS and p95 <= MATCH_P95_SPACINGS
    return (0.0, True) if same else (raw, False)
