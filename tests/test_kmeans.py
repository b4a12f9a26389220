"""pixie_gs.kmeans.kmeans_pp is SciPy's kmeans2(minit="++", seed=...), without importing scipy."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.cluster.vq import kmeans2

from pixie_gs.diagnose.synthetic import two_part_block
from pixie_gs.kmeans import kmeans_pp


@pytest.mark.parametrize("seed", range(12))
def test_matches_scipy_kmeans2(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, k = int(rng.integers(5, 400)), int(rng.integers(1, 6))
    data = rng.normal(size=(n, 3)) * rng.uniform(0.01, 2.0, size=3)
    if seed % 3 == 0:   # well-separated blobs as well as one cloud
        data[: n // 2] += 5.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)   # an empty cluster: both warn
        ref_c, ref_l = kmeans2(data, k, seed=seed % 4, minit="++")
        ours_c, ours_l = kmeans_pp(data, k, seed=seed % 4)
    assert np.array_equal(ours_l, ref_l)
    assert np.array_equal(ours_c, ref_c)


def test_diagnose_geometry_labels_match() -> None:
    """The tracked points of the runtime benchmark (1000 of a 20k-Gaussian block), k = 4, seed 0."""
    means = two_part_block(20000, seed=0).means.astype(np.float64)
    ids = np.sort(np.random.default_rng(7).choice(len(means), 1000, replace=False))
    _, ref = kmeans2(means[ids], 4, seed=0, minit="++")
    _, ours = kmeans_pp(means[ids], 4, seed=0)
    assert np.array_equal(ours, ref)
    assert len(np.unique(ours)) == 4


def test_bad_input() -> None:
    with pytest.raises(ValueError):
        kmeans_pp(np.zeros((0, 3)), 2)
