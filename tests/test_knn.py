"""numpy k-nearest neighbours (pixie_gs/knn.py) and the checks built on it (diagnose/checks.py),
each against a plain reference: brute force over all pairs, and the per-track loop that
outlier_tracks replaced (checks.outlier_distances_reference)."""
from __future__ import annotations

import numpy as np
import pytest

from pixie_gs.diagnose.checks import (_nan_median, gaussian_spacing, icp, outlier_distances,
                                     outlier_distances_reference, outlier_tracks)
from pixie_gs.knn import CellGrid, knn, knn_brute


def _clouds():
    rng = np.random.default_rng(3)
    yield "volume", rng.random((3000, 3)), None, 2
    yield "plane, queries off it", np.c_[rng.random((2000, 2)), np.zeros(2000)], rng.random((300, 3)) * 2 - 0.5, 7
    yield "tight cluster + sparse far points", np.r_[rng.normal(size=(1500, 3)) * 1e-3, rng.random((60, 3)) * 10], \
        rng.random((200, 3)) * 10, 8
    yield "fewer points than k", rng.random((3, 3)), rng.random((10, 3)), 5


@pytest.mark.parametrize("name,points,queries,k", list(_clouds()), ids=lambda v: v if isinstance(v, str) else "")
def test_knn_matches_brute_force(name, points, queries, k):
    queries = points if queries is None else queries
    d, i = knn(points, queries, k)
    d_ref, _ = knn_brute(points, queries, k)
    assert d.shape == d_ref.shape == (len(queries), min(k, len(points)))
    assert np.array_equal(d, d_ref)                                   # same distances, nearest first
    assert np.allclose(np.linalg.norm(points[i] - queries[:, None], axis=2), d)   # indices give them


def test_knn_of_far_and_non_finite_queries():
    rng = np.random.default_rng(4)
    points = rng.random((200, 3))
    q = np.array([[np.nan, 0, 0], [np.inf, 0, 0], [1e300, 1e300, -1e300], [40.0, -3.0, 2.0], [0.5, 0.5, 0.5]])
    with np.errstate(all="raise"):
        d, i = knn(points, q, 3)
    assert np.all(np.isinf(d[:2])) and np.all(i[:2] == -1)           # nothing is near a non-finite point
    d_ref, _ = knn_brute(points, q[2:], 3)
    assert np.array_equal(d[2:], d_ref)


def test_knn_brute_is_right_on_a_lattice():
    g = np.stack(np.meshgrid(*[np.arange(4.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    d, _ = knn_brute(g, np.array([[0.0, 0.0, 0.0], [1.5, 1.5, 1.5]]), 7)
    assert np.allclose(d[0], [0, 1, 1, 1, np.sqrt(2), np.sqrt(2), np.sqrt(2)])
    assert np.allclose(d[1], np.sqrt(0.75))                           # 8 corners of the cell around it
    with pytest.raises(ValueError):
        CellGrid(np.zeros((0, 3)))


def test_gaussian_spacing_and_icp():
    rng = np.random.default_rng(0)
    g = np.stack(np.meshgrid(*[np.arange(10.0)] * 3, indexing="ij"), -1).reshape(-1, 3) * 0.02
    assert gaussian_spacing(g + rng.normal(scale=1e-6, size=g.shape)) == pytest.approx(0.02, rel=1e-3)
    pts = g[rng.choice(len(g), 200, replace=False)]
    a = np.radians(4.0)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    moved = (pts - 0.09) @ R.T + 0.09 + [0.004, -0.003, 0.002]      # a small rigid misplacement
    R_fit, t_fit = icp(moved, g)
    assert np.allclose(moved @ R_fit.T + t_fit, pts, atol=1e-6)


def test_outlier_tracks_match_the_per_track_loop():
    rng = np.random.default_rng(5)
    T, M = 30, 150
    rest = rng.random((M, 3))
    part = (rest[:, 2] > 0.4).astype(int)
    part[:2] = 7                                                      # a part too small to judge
    r = 0.01 * rest[None, :, :1] * np.linspace(0, 1, T)[:, None, None] + rng.normal(scale=1e-3, size=(T, M, 3))
    r[:, 40] += 0.05                                                  # a slipped track
    visible = rng.random((T, M)) > 0.15
    visible[:, 41] = False                                            # never seen
    visible[3:, 42] = False                                           # seen twice... then lost
    r = np.where(visible[:, :, None], r, np.nan)
    found, z = outlier_tracks(r, visible, rest, part, sigma=1e-3)
    d = outlier_distances_reference(r, visible, rest, part)
    assert np.array_equal(outlier_distances(r, visible, rest, part) == 0, d == 0)
    med = np.median(d)
    z_ref = (d - med) / max(np.median(np.abs(d - med)) * 1.4826, 3e-3)
    assert np.allclose(z, z_ref, rtol=1e-12, atol=1e-12)
    assert found[40] and found.sum() == 1


def test_nan_median_is_numpys():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(40, 6, 3))
    a[rng.random(a.shape) < 0.4] = np.nan
    a[0, :, 0] = np.nan                                               # all missing → NaN
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        ref = np.nanmedian(a, axis=1)
    assert np.allclose(_nan_median(a, axis=1), ref, equal_nan=True, rtol=0, atol=1e-15)

