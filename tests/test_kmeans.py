"""pixie_gs.kmeans.kmeans_pp: k-means with k-means++ seeds (no scipy), on data whose clusters are known."""
from __future__ import annotations

import numpy as np
import pytest

from pixie_gs.diagnose.locate import spatial_clusters
from pixie_gs.diagnose.synthetic import two_part_block
from pixie_gs.kmeans import kmeans_pp


def blobs(seed: int, k: int, per: int = 60, dim: int = 3, spread: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """k tight blobs (σ = spread) whose centres are ≥ 2 apart, shuffled; (points, true blob of each)."""
    rng = np.random.default_rng(seed)
    centres = np.zeros((k, dim))
    for i in range(k):
        centres[i, i % dim] = 2.0 * (i // dim + 1)
    truth = np.repeat(np.arange(k), per)
    points = centres[truth] + rng.normal(scale=spread, size=(k * per, dim))
    order = rng.permutation(len(points))
    return points[order], truth[order]


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """True when labels a and b group the points identically (up to renumbering)."""
    pairs = set(zip(a.tolist(), b.tolist()))
    return len(pairs) == len(set(a.tolist())) == len(set(b.tolist()))


@pytest.mark.parametrize("seed", range(20))
def test_finds_well_separated_blobs(seed: int) -> None:
    k = 2 + seed % 5
    points, truth = blobs(seed, k)
    centres, labels = kmeans_pp(points, k, seed=seed)
    assert centres.shape == (k, 3) and labels.shape == (len(points),)
    assert same_partition(labels, truth)
    for j in range(k):   # each centre is its cluster's mean
        assert np.allclose(centres[j], points[labels == j].mean(axis=0), rtol=0, atol=1e-12)


def test_same_partition_same_numbers_for_every_seed() -> None:
    points, truth = blobs(3, 4)
    runs = [kmeans_pp(points, 4, seed=s) for s in range(10)]
    for centres, labels in runs:
        assert np.array_equal(labels, runs[0][1]) and np.array_equal(centres, runs[0][0])
    # numbered by the centres' first coordinate (ties: the next one)
    assert np.all(np.diff(runs[0][0][:, 0]) >= 0)


def test_deterministic_per_seed() -> None:
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(500, 3))          # one cloud: the partition depends on the seeds
    a = kmeans_pp(cloud, 5, seed=11)
    b = kmeans_pp(cloud, 5, seed=11)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    partitions = {kmeans_pp(cloud, 5, seed=s)[1].tobytes() for s in range(8)}
    assert len(partitions) > 1                  # the seed is used


def test_lloyd_fixed_point() -> None:
    """Converged: every point is nearest to its own centre and every centre is its points' mean."""
    rng = np.random.default_rng(5)
    cloud = rng.uniform(size=(400, 2))
    centres, labels = kmeans_pp(cloud, 6, seed=2)
    d2 = ((cloud[:, None, :] - centres[None]) ** 2).sum(-1)
    assert np.array_equal(np.argmin(d2, axis=1), labels)
    for j in range(6):
        assert np.allclose(centres[j], cloud[labels == j].mean(axis=0), rtol=0, atol=1e-12)


# six points on which Lloyd's iteration from the seeds default_rng(266) draws empties a cluster
# (found by search): plain Lloyd would end with 2 of the 3 clusters
EMPTYING = np.array([[0.2097, -0.0087], [0.5902, 0.9518], [0.0492, -1.0139], [0.8773, 0.9749], [0.5233, 1.5638],
                     [-0.4450, 0.1919]])


def test_empty_cluster_is_refilled() -> None:
    from pixie_gs.kmeans import _plus_plus_seeds, _sq_dist

    centres = _plus_plus_seeds(EMPTYING, 3, np.random.default_rng(266))
    emptied = False
    for _ in range(10):   # plain Lloyd from the same seeds: a cluster loses all its points
        labels = np.argmin(_sq_dist(EMPTYING, centres), axis=1)
        if len(np.unique(labels)) < 3:
            emptied = True
            break
        centres = np.stack([EMPTYING[labels == j].mean(axis=0) for j in range(3)])
    assert emptied
    centres, labels = kmeans_pp(EMPTYING, 3, seed=266)
    assert np.array_equal(np.bincount(labels, minlength=3), np.bincount(labels)) and np.all(np.bincount(labels) > 0)
    assert len(centres) == 3 and np.isfinite(centres).all()
    d2 = _sq_dist(EMPTYING, centres)
    assert np.array_equal(np.argmin(d2, axis=1), labels)   # and it converged: a Lloyd fixed point


def test_more_clusters_than_distinct_points() -> None:
    points = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 3.0]])
    centres, labels = kmeans_pp(points, 10, seed=0)      # k > N, and only 3 distinct points
    assert centres.shape == (3, 2)
    assert np.array_equal(centres, [[0.0, 0.0], [0.0, 3.0], [1.0, 0.0]])
    assert np.array_equal(labels, [0, 2, 2, 1])
    centres, labels = kmeans_pp(np.ones((5, 3)), 4, seed=3)  # one distinct point: one cluster
    assert centres.shape == (1, 3) and np.array_equal(labels, np.zeros(5))


def test_diagnose_geometry_clusters() -> None:
    """The tracked points of the runtime benchmark (1000 of a 20k-Gaussian block), k = 4: four
    compact groups of similar size, the same for every seed in numbering and content."""
    means = two_part_block(20000, seed=0).means.astype(np.float64)
    ids = np.sort(np.random.default_rng(7).choice(len(means), 1000, replace=False))
    labels = spatial_clusters(means[ids], 4)
    counts = np.bincount(labels)
    assert len(counts) == 4 and counts.min() >= 100
    extent = np.ptp(means[ids], axis=0).max()
    for j in range(4):   # compact: no cluster spans the object
        assert np.ptp(means[ids][labels == j], axis=0).max() < extent


def test_bad_input() -> None:
    with pytest.raises(ValueError):
        kmeans_pp(np.zeros((0, 3)), 2)
    with pytest.raises(ValueError):
        kmeans_pp(np.zeros((4, 3)), 0)
    with pytest.raises(ValueError, match="finite"):
        kmeans_pp(np.array([[0.0, np.nan]]), 1)
