"""k-means with k-means++ seeding on a few hundred to a few thousand points, without scipy.

Why: diagnose labels the tracked points' rest positions with 4 spatial clusters (locate.py, the
report's "where"); importing scipy.cluster.vq for it pulls in scipy.spatial, ~0.3 s of CPU here
and ~0.8 s on the H100 host, on the critical path of a GPU diagnosis. This is SciPy's
`kmeans2(data, k, iter=10, minit="++", seed=seed)` for 2-D float64 data transcribed step for step
(the legacy RandomState stream an integer `seed` gives, k-means++ seeding, nearest-centroid
labels with the first centroid winning ties, centroid means, empty clusters kept where they
were), so the labels are SciPy's (tests/test_kmeans.py). SciPy is BSD-3-licensed
(scipy/cluster/vq.py; Copyright (c) 2001-2002 Enthought, Inc. and 2003-2024 SciPy Developers).
"""
from __future__ import annotations

import warnings

import numpy as np


def _sq_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) squared Euclidean distances, summed over coordinates in order."""
    d = np.zeros((len(a), len(b)))
    for j in range(a.shape[1]):
        d += np.square(a[:, None, j] - b[None, :, j])
    return d


def _seed_pp(data: np.ndarray, k: int, rng: np.random.RandomState) -> np.ndarray:
    """k-means++ initial centroids (scipy.cluster.vq._kpp)."""
    init = np.empty((k, data.shape[1]))
    for i in range(k):
        if i == 0:
            idx = rng.randint(data.shape[0])
        else:
            d2 = _sq_distances(init[:i], data).min(axis=0)
            probs = d2 / d2.sum()
            idx = int(np.searchsorted(probs.cumsum(), rng.uniform()))
        init[i] = data[idx]
    return init


def kmeans_pp(data: np.ndarray, k: int, seed: int = 0, iterations: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(centroids (k,D), labels (N,)) of `data` (N,D): `iterations` Lloyd steps from k-means++
    seeds drawn with np.random.RandomState(seed) — scipy.cluster.vq.kmeans2(data, k, iter,
    minit="++", seed=seed)."""
    data = np.asarray(data, np.float64)
    if data.ndim != 2 or len(data) < 1 or k < 1:
        raise ValueError("kmeans_pp needs (N, D) data with N ≥ 1 and k ≥ 1")
    code_book = _seed_pp(data, int(k), np.random.RandomState(seed))
    labels = np.zeros(len(data), np.intp)
    for _ in range(iterations):
        labels = np.argmin(_sq_distances(data, code_book), axis=1)
        sums = np.zeros_like(code_book)
        np.add.at(sums, labels, data)
        counts = np.bincount(labels, minlength=len(code_book))
        has = counts > 0
        new = code_book.copy()
        new[has] = sums[has] / counts[has, None]
        if not has.all():
            warnings.warn("One of the clusters is empty. Re-run kmeans with a different initialization.",
                          UserWarning, stacklevel=2)
        code_book = new
    return code_book, labels
