"""k-means with k-means++ seeding on a few hundred to a few thousand points, without scipy.

Why: diagnose groups the tracked points' rest positions into 4 spatial clusters (locate.py, the
report's "where"); importing scipy.cluster.vq for it pulls in scipy.spatial, ~0.3 s of CPU here
and ~0.8 s on the H100 host, on the critical path of a GPU diagnosis.

How: seeds by D² sampling (Arthur & Vassilvitskii 2007: the first centre a uniformly drawn
point, each next one a point drawn with probability proportional to its squared distance D² to
the nearest centre chosen so far), in its greedy form (a few candidates per step, the one that
lowers the total D² most kept: two seeds in one well-separated group become rare), then Lloyd's alternation (each point to its nearest centre,
each centre to the mean of its points) until no point changes cluster. A cluster left empty
takes over the point farthest from its own centre (the worst-served point), so every returned
cluster has points. Clusters are numbered by their centres in lexicographic order of the
coordinates, so the same partition gets the same numbers whatever order the seeds came in.
Deterministic for a given seed (numpy's default_rng).
"""
from __future__ import annotations

import numpy as np


def _sq_dist(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(N, K) squared Euclidean distances (differences, not the expanded form: never negative)."""
    diff = points[:, None, :] - centres[None, :, :]
    return np.einsum("nkd,nkd->nk", diff, diff)


def _plus_plus_seeds(points: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """k distinct centres by greedy D² sampling (k ≤ the number of distinct points): each step draws
    2 + ⌊ln k⌋ candidates and keeps the one that lowers Σ D² most."""
    trials = 2 + int(np.log(k))
    chosen = [int(rng.integers(len(points)))]
    nearest = _sq_dist(points, points[chosen]).ravel()
    for _ in range(1, k):
        # a point already chosen has weight 0, so it cannot be drawn again
        cands = rng.choice(len(points), size=trials, p=nearest / nearest.sum())
        after = np.minimum(nearest[:, None], _sq_dist(points, points[cands]))   # (N, trials)
        best = int(np.argmin(after.sum(axis=0)))
        chosen.append(int(cands[best]))
        nearest = after[:, best]
    return points[chosen].copy()


def _refill_empty(points: np.ndarray, labels: np.ndarray, d2: np.ndarray, k: int) -> np.ndarray:
    """labels with every empty cluster given the point farthest from its centre, taken from a
    cluster that keeps at least one point."""
    labels = labels.copy()
    for empty in np.flatnonzero(np.bincount(labels, minlength=k) == 0):
        counts = np.bincount(labels, minlength=k)
        own = d2[np.arange(len(points)), labels]
        own[counts[labels] < 2] = -1.0       # a lone point stays: its cluster would empty
        labels[int(np.argmax(own))] = empty
    return labels


def kmeans_pp(points: np.ndarray, k: int, seed: int = 0, max_iter: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """(centres (K, D), labels (N,) in 0..K-1) of k-means on `points` (N, D), K = min(k, number of
    distinct points): k-means++ seeds drawn with default_rng(seed), then at most `max_iter`
    Lloyd iterations (stops when the labels repeat). Every cluster is non-empty; clusters are
    numbered in lexicographic order of their centres."""
    points = np.asarray(points, np.float64)
    if points.ndim != 2 or len(points) < 1 or k < 1 or max_iter < 1:
        raise ValueError(f"kmeans_pp needs points (N, D) with N ≥ 1, k ≥ 1 and max_iter ≥ 1, got {points.shape}, "
                         f"k={k}, max_iter={max_iter}")
    if not np.isfinite(points).all():
        raise ValueError("kmeans_pp needs finite points")
    k = min(int(k), len(np.unique(points, axis=0)))
    centres = _plus_plus_seeds(points, k, np.random.default_rng(seed))
    labels = np.full(len(points), -1)
    for _ in range(max_iter):
        d2 = _sq_dist(points, centres)
        new = _refill_empty(points, np.argmin(d2, axis=1), d2, k)
        if np.array_equal(new, labels):
            break
        labels = new
        counts = np.bincount(labels, minlength=k)
        centres = np.stack([np.bincount(labels, weights=points[:, j], minlength=k) for j in range(points.shape[1])],
                           axis=1) / counts[:, None]
    order = np.lexsort(centres.T[::-1])          # first coordinate first
    rank = np.empty(k, np.intp)
    rank[order] = np.arange(k)
    return centres[order], rank[labels]
