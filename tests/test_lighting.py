"""Baked lighting (pixie_gs/dataset/lighting.py): shade follows occlusion, uniform light keeps the paint,
labels and geometry stay, and a share of 0 draws nothing."""
from __future__ import annotations

import numpy as np
import pytest

from pixie_gs.dataset import lighting
from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.generate import generate_split
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.errors import InputError
from pixie_gs.splat import SplatCloud

FLAT = np.log(np.array([0.01, 0.01, 0.0005]))  # discs lying in the xy plane: normal +z


def _layer(x: tuple[float, float], z: float, spacing: float = 0.01) -> np.ndarray:
    xs = np.arange(x[0], x[1], spacing)
    ys = np.arange(0.0, 1.0, spacing)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], axis=1)


def _cloud(points: np.ndarray, rgb=(0.5, 0.5, 0.5)) -> SplatCloud:
    n = len(points)
    return SplatCloud.from_arrays(points, log_scales=np.tile(FLAT, (n, 1)), rgb=np.tile(rgb, (n, 1)))


def _sphere(n: int = 6000, radius: float = 0.5) -> SplatCloud:
    """Flat Gaussians on a sphere's surface, each lying in the tangent plane (normal = radial)."""
    from pixie_gs.splat import rotmat_to_quat

    v = np.random.default_rng(0).normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    helper = np.where(np.abs(v[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(v, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    R = np.stack([t1, np.cross(v, t1), v], axis=2)  # columns: two tangents, then the normal (smallest axis)
    return SplatCloud.from_arrays(v * radius, log_scales=np.tile(FLAT, (n, 1)), rotations=rotmat_to_quat(R))


def test_a_ball_is_lit_from_above():
    """A hollow ball under a sky and a sun at 25–80° elevation: its lower cap faces away from the sun, so for
    every draw it is darker than the upper cap (occlusion reaches RAY_STEPS cells, a quarter of the ball, so the
    lower cap still sees the sky through the hollow: the margin is the sun's share)."""
    ball = _sphere()
    z = ball.means[:, 2] / 0.5
    for seed in range(6):
        lit, record = lighting.bake_lighting(_sphere(), np.random.default_rng(seed))
        brightness = lit.rgb().mean(axis=1)
        assert brightness[z < -0.7].mean() < 0.95 * brightness[z > 0.7].mean(), (seed, record)


def test_uniform_light_without_sheen_or_gloss_keeps_the_paint(monkeypatch):
    """Gaussians far apart on a floor (nothing between them and the sky) facing up get one irradiance, which
    the exposure maps to the lit faces' level: with exposure 1, no sheen and no highlight every Gaussian keeps
    its painted colour (the gamma round trip)."""
    monkeypatch.setattr(lighting, "EXPOSURE", (1.0, 1.0))
    monkeypatch.setattr(lighting, "SHEEN", (0.0, 0.0))
    monkeypatch.setattr(lighting, "GLOSS_SHARE", 0.0)
    # four Gaussians 15.5 cells apart (beyond every ray's reach), and a fifth at the far corner that sets the grid's
    # extent, so none of the four sits on the grid's last cell boundary
    floor = np.concatenate([_layer((0.0, 1.0), 0.0, spacing=0.5), [[1.0, 1.0, 0.0]]])
    paint = np.random.default_rng(1).uniform(0.05, 0.95, (len(floor), 3))
    cloud = SplatCloud.from_arrays(floor, log_scales=np.tile(FLAT, (len(floor), 1)), rgb=paint)
    lit, _ = lighting.bake_lighting(cloud, np.random.default_rng(2))
    np.testing.assert_allclose(lit.rgb()[:4], paint[:4], atol=1e-4)


def test_sheen_desaturates_and_keeps_the_leading_channel(monkeypatch):
    monkeypatch.setattr(lighting, "SHEEN", (0.08, 0.08))
    monkeypatch.setattr(lighting, "GLOSS_SHARE", 0.0)
    leaf = (0.2, 0.45, 0.15)
    lit, _ = lighting.bake_lighting(_cloud(_layer((0.0, 1.0), 0.0), leaf), np.random.default_rng(3))
    rgb = lit.rgb().mean(axis=0)
    saturation = lambda c: (max(c) - min(c)) / max(c)  # noqa: E731  (HSV saturation)
    assert rgb[1] > rgb[0] and rgb[1] > rgb[2]
    assert saturation(rgb) < 0.8 * saturation(leaf)


def test_labels_and_geometry_stay_and_share_zero_draws_nothing():
    spec = load_class_table()["shrubs"]
    plain, plain_record = build_object(spec, 1234, 6000, realistic=True, lighting_share=0.0)
    lit, lit_record = build_object(spec, 1234, 6000, realistic=True, lighting_share=1.0)
    assert "lighting" not in plain_record["realism"] and "lighting" in lit_record["realism"]
    for name in ("means", "log_scales", "rotations", "opacity_logits", "sh_rest"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(lit, name))
    for name in ("material_id", "E", "nu", "density", "part_id"):
        np.testing.assert_array_equal(plain.get(name), lit.get(name))
    rgb = lit.rgb()
    assert np.isfinite(rgb).all() and rgb.min() >= 0.0 and rgb.max() <= 1.0
    assert not np.allclose(rgb, plain.rgb())


def test_lighting_share_outside_zero_to_one_is_refused(tmp_path):
    with pytest.raises(InputError, match="--lighting"):
        generate_split(tmp_path / "d", 2, lighting_share=1.5)
    assert not (tmp_path / "d").exists()
