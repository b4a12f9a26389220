"""Feature field: voxel values against hand-computed Gaussians, mass, normalisation, channel choice."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from pixie_gs.field import (
    BASE_FEATURES, DENSITY_CHANNELS, extra_feature_names, feature_grid, grid_channels, splat_field, up_rotation,
)
from pixie_gs.splat import SplatCloud, quat_to_rotmat


def _cov(scales, quat):
    r = quat_to_rotmat(np.array([quat], np.float64))[0]
    return r @ np.diag(np.asarray(scales, np.float64) ** 2) @ r.T


def _t(a):
    return torch.as_tensor(np.asarray(a), dtype=torch.float32)


@pytest.mark.parametrize("filter_voxels", [0.0, 0.5])
def test_density_at_voxels_matches_hand_computed_gaussian(filter_voxels):
    n = 16
    mean = np.array([0.51, 0.47, 0.55])
    cov = _cov([0.05, 0.02, 0.03], [0.9, 0.1, 0.3, -0.2])
    alpha = 0.7
    dens, sums = splat_field(_t(mean[None]), _t(cov[None]), _t([alpha]), _t([[2.0, -1.0]]), n,
                             filter_voxels=filter_voxels, max_radius_voxels=8)
    dens = dens.view(n, n, n).double().numpy()
    cov_f = cov + (filter_voxels / n) ** 2 * np.eye(3)
    prec = np.linalg.inv(cov_f)
    checked = 0
    centre = np.floor(mean * n).astype(int)
    for ijk in [tuple(centre + o) for o in np.ndindex(5, 5, 5)]:
        ijk = tuple(int(v) - 2 for v in ijk)
        x = (np.array(ijk) + 0.5) / n
        d = x - mean
        maha = d @ prec @ d
        expected = alpha * math.exp(-0.5 * maha) if maha <= 9.0 else 0.0
        assert dens[ijk] == pytest.approx(expected, rel=1e-4, abs=1e-7)
        checked += expected > 0.05
    assert checked >= 5
    # one Gaussian: the weighted feature mean is its own feature wherever it contributes
    sums = sums.view(n, n, n, 2).double().numpy()
    occ = dens > 1e-6
    assert np.allclose(sums[occ] / dens[occ][:, None], [2.0, -1.0], atol=1e-5)


def test_two_gaussians_feature_is_opacity_weighted_mean():
    n = 8
    means = np.array([[0.45, 0.5, 0.5], [0.58, 0.5, 0.5]])
    covs = np.stack([np.eye(3) * 0.06 ** 2, np.eye(3) * 0.04 ** 2])
    alphas = np.array([0.9, 0.4])
    feats = np.array([[1.0], [3.0]])
    dens, sums = splat_field(_t(means), _t(covs), _t(alphas), _t(feats), n, filter_voxels=0.0)
    values, occ = grid_channels(dens, sums, n)
    x = (np.array([4, 4, 4]) + 0.5) / n
    w = [a * math.exp(-0.5 * (x - m) @ np.linalg.inv(c) @ (x - m)) for m, c, a in zip(means, covs, alphas)]
    assert float(dens.view(n, n, n)[4, 4, 4]) == pytest.approx(sum(w), rel=1e-5)
    assert float(values[0, 2, 4, 4, 4]) == pytest.approx((w[0] * 1 + w[1] * 3) / (w[0] + w[1]), rel=1e-5)
    assert float(values[0, 0, 4, 4, 4]) == pytest.approx(1 - math.exp(-sum(w)), rel=1e-5)  # density channel
    assert bool(occ[0, 4, 4, 4])


def test_total_density_is_the_truncated_gaussian_mass():
    """Σ over voxels ≈ α (2π)^{3/2} √det Σ' n³ · P(χ²₃ ≤ 9) for a Gaussian well inside the grid."""
    n = 32
    cov = _cov([0.04, 0.025, 0.03], [0.8, -0.3, 0.2, 0.4])
    dens, _ = splat_field(_t([[0.5, 0.49, 0.52]]), _t(cov[None]), _t([0.8]), torch.zeros(1, 1), n,
                          filter_voxels=0.5, max_radius_voxels=8)
    cov_f = cov + (0.5 / n) ** 2 * np.eye(3)
    chi2_3_below_9 = math.erf(3 / math.sqrt(2)) - math.sqrt(2 / math.pi) * 3 * math.exp(-4.5)
    expected = 0.8 * (2 * math.pi) ** 1.5 * math.sqrt(np.linalg.det(cov_f)) * n ** 3 * chi2_3_below_9
    assert float(dens.sum()) == pytest.approx(expected, rel=0.02)


def test_feature_grid_uses_the_splat_unit_cube_and_its_channels():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(400, 3)) * [2.0, 1.0, 0.5] + [10.0, -3.0, 1.0]
    cloud = SplatCloud.from_arrays(pts, log_scales=np.full((400, 3), np.log(0.2)), rgb=np.tile([0.2, 0.6, 0.9], (400, 1)))
    grid = feature_grid(cloud, resolution=16)
    unit, tf = cloud.normalized()
    assert np.allclose(grid.extra["means_unit"], unit.means, atol=1e-5)
    assert grid.transform.scale == pytest.approx(tf.scale, rel=1e-6)
    assert grid.channels == list(DENSITY_CHANNELS + BASE_FEATURES)
    occ = grid.occupancy
    assert occ.any() and np.array_equal(occ, grid.channel("occupancy") > 0.5)
    # a single colour everywhere: every occupied voxel reads exactly that RGB, empty ones zero
    for name, value in zip("rgb", [0.2, 0.6, 0.9]):
        ch = grid.channel(name)
        assert np.allclose(ch[occ], value, atol=1e-3)
        assert np.all(ch[~occ] == 0)
    assert np.array_equal(occ, grid.extra["density"] > 0.01)


def test_label_attributes_and_normals_are_never_features():
    cloud = SplatCloud.from_arrays(np.random.default_rng(1).normal(size=(50, 3)))
    for name in ("nx", "ny", "nz", "clip_0", "clip_1", "part_id"):
        cloud.set(name, np.ones(50), np.int32 if name == "part_id" else np.float32)
    cloud.set_materials(np.zeros(50), np.full(50, 1e5), np.full(50, 0.3), np.full(50, 1000.0))
    cloud.set("instance", np.arange(50), np.int32)
    assert extra_feature_names(cloud) == ["clip_0", "clip_1"]


@pytest.mark.parametrize("up", ["z", "y", "-y", "x", "-x", "-z"])
def test_up_rotation_is_proper_and_points_up(up):
    r = up_rotation(up)
    axis = {"x": 0, "y": 1, "z": 2}[up[-1]]
    v = np.zeros(3)
    v[axis] = -1.0 if up.startswith("-") else 1.0
    assert np.allclose(r @ v, [0, 0, 1])
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_closed_form_3x3_inverse_and_eigenvalues_match_numpy():
    from pixie_gs.field import eigvals_sym_3x3, inverse_3x3

    rng = np.random.default_rng(2)
    rot = quat_to_rotmat(rng.normal(size=(200, 4)))
    sd = np.exp(rng.uniform(-6, 0, size=(200, 3)))
    cov = rot @ (sd[:, :, None] ** 2 * np.eye(3)) @ rot.transpose(0, 2, 1)
    cov[:3] = np.eye(3) * 0.01  # isotropic: the trigonometric formula's degenerate case
    ev = eigvals_sym_3x3(torch.as_tensor(cov)).numpy()
    assert np.allclose(ev, np.linalg.eigvalsh(cov), rtol=1e-6, atol=1e-12 * cov.max())
    inv = inverse_3x3(torch.as_tensor(cov)).numpy()
    assert np.allclose(inv @ cov, np.eye(3), atol=1e-6)
