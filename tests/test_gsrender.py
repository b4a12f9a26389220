"""pixie_gs.gsrender: the fast splat renderer against a brute-force per-pixel reference and against
analytic answers (projected Gaussian profile, SH colour along a known direction, camera files)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from pixie_gs.gsrender import render, render_modes
from pixie_gs.gsrender.camera import Camera, look_at, orbit_cameras, read_cameras
from pixie_gs.gsrender.raster import Gaussians, project, rasterize
from pixie_gs.gsrender.reference import real_sh_basis, reference_render
from pixie_gs.gsrender.sh import basis, coefficients
from pixie_gs.splat import SplatCloud

BLACK = (0.0, 0.0, 0.0)


def gaussians(means, scales, quats, opacities, sh):
    return Gaussians(*(torch.tensor(np.asarray(a), dtype=torch.float32) for a in (means, scales, quats, opacities, sh)))


def random_scene(seed: int, n: int, degree: int = 3, spread: float = 0.3):
    """Anisotropic (scale ratios up to ~20), randomly rotated, overlapping Gaussians with SH."""
    rng = np.random.default_rng(seed)
    means = rng.normal(scale=spread, size=(n, 3))
    scales = np.exp(rng.uniform(np.log(0.01), np.log(0.25), size=(n, 3)))
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    opacities = rng.uniform(0.05, 1.0, n)
    sh = rng.normal(scale=0.4, size=(n, (degree + 1) ** 2, 3))
    return means, scales, quats, opacities, sh


@pytest.mark.parametrize("backend", ["warp", "torch"])
@pytest.mark.parametrize("seed", [0, 1])
def test_fast_renderer_matches_brute_force_reference(backend, seed):
    means, scales, quats, opacities, sh = random_scene(seed, 70)
    # a stack of nearly opaque splats in front, so some pixels stop early (transmittance < 1e-4)
    means[:6] = [0.0, 0.0, 0.0] + np.linspace(-0.3, 0.3, 6)[:, None] * [1, -0.8, 0.6]
    scales[:6] = 0.15
    opacities[:6] = 1.0
    cam = look_at([1.8, -1.4, 0.9], [0, 0, 0], [0, 0, 1], 48, 40, fov_y_deg=50)
    g = gaussians(means, scales, quats, opacities, sh)
    fast = render(g, cam, background=(0.2, 0.4, 0.9), backend=backend).numpy()
    ref = np.clip(reference_render(means, scales, quats, opacities, sh, cam, background=(0.2, 0.4, 0.9)), 0, 1)
    assert (np.abs(ref - 0.5) < 0.45).mean() > 0.3  # the scene really covers the image
    err = np.abs(fast - ref)
    assert err.mean() < 1 / 255
    assert err.max() < 4 / 255  # the same splats composited in the same order, up to float32 rounding
    _, trans = rasterize(project(g, cam), torch.ones(len(means), 3), cam.width, cam.height, backend=backend)
    assert float(trans.min()) < 1e-3  # early termination happened somewhere


@pytest.mark.parametrize("backend", ["warp", "torch"])
def test_partly_visible_scene_with_splats_behind_the_camera(backend):
    means, scales, quats, opacities, sh = random_scene(5, 60, degree=1, spread=1.0)
    cam = look_at([0.0, -1.2, 0.2], [0, 0, 0], [0, 0, 1], 40, 32, fov_y_deg=70)
    g = gaussians(means, scales, quats, opacities, sh)
    assert (project(g, cam).depth < 0).any()
    fast = render(g, cam, background=BLACK, backend=backend).numpy()
    ref = np.clip(reference_render(means, scales, quats, opacities, sh, cam, background=BLACK), 0, 1)
    assert np.abs(fast - ref).mean() < 1 / 255


@pytest.mark.parametrize("backend", ["warp", "torch"])
def test_single_isotropic_gaussian_is_the_analytic_2d_gaussian(backend):
    sigma, z, f, opacity = 0.05, 2.0, 60.0, 0.8
    cam = Camera(R=np.eye(3), t=np.zeros(3), fx=f, fy=f, cx=32.0, cy=32.0, width=64, height=64)
    white_dc = np.full((1, 1, 3), 0.5 / 0.28209479177387814)  # SH colour 1.0 in every channel
    g = gaussians([[0.0, 0.0, z]], [[sigma] * 3], [[1.0, 0, 0, 0]], [opacity], white_dc)
    image = render(g, cam, background=BLACK, backend=backend).numpy()
    s2 = (f * sigma / z) ** 2 + 0.3  # projected variance (px²) plus the 3DGS low-pass filter
    yy, xx = np.mgrid[:64, :64] + 0.5
    expected = opacity * np.exp(-((xx - 32) ** 2 + (yy - 32) ** 2) / (2 * s2))
    expected[expected < 1 / 255] = 0.0
    for c in range(3):
        np.testing.assert_allclose(image[:, :, c], expected, atol=2e-6)
    # off the optical axis the centre lands at f·x/z + cx
    g = gaussians([[0.4, -0.2, z]], [[0.02] * 3], [[1.0, 0, 0, 0]], [1.0], white_dc)
    image = render(g, cam, background=BLACK, backend=backend).numpy()[:, :, 0]
    weights = image / image.sum()
    assert np.sum(weights * xx) == pytest.approx(f * 0.4 / z + 32, abs=1e-3)
    assert np.sum(weights * yy) == pytest.approx(f * -0.2 / z + 32, abs=1e-3)


def test_sh_colour_along_a_known_direction():
    # camera on −z looking +z: the view direction is +z, where Y_1^0 = sqrt(3 / 4π) and Y_2^0 = sqrt(5/16π)·2
    cam = look_at([0, 0, -3.0], [0, 0, 0], [0, 1, 0], 32, 32, fov_y_deg=40)
    sh = np.zeros((1, 9, 3))
    sh[0, 2] = [0.5, -0.5, 0.0]  # Y_1^0 coefficient per channel
    sh[0, 6] = [0.0, 0.0, 0.3]  # Y_2^0
    g = gaussians([[0, 0, 0]], [[1.0] * 3], [[1.0, 0, 0, 0]], [1.0], sh)
    centre = render(g, cam, background=BLACK).numpy()[16, 16]
    y10, y20 = np.sqrt(3 / (4 * np.pi)), np.sqrt(5 / (16 * np.pi)) * 2
    expected = 0.99 * np.clip(0.5 + np.array([0.5 * y10, -0.5 * y10, 0.3 * y20]), 0, None)  # α clamps at 0.99
    np.testing.assert_allclose(centre, expected, atol=1e-5)


def test_sh_table_matches_scipy_spherical_harmonics():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    table = np.stack(basis(d[:, 0], d[:, 1], d[:, 2], 3), axis=1)
    np.testing.assert_allclose(table, real_sh_basis(d, 3), atol=1e-12)


def test_f_rest_is_channel_major():
    # degree 3: 15 f_rest per channel; f_rest_0 is red's first degree-1 coefficient, f_rest_15 green's
    rest = np.zeros((1, 45), np.float32)
    rest[0, 0], rest[0, 15], rest[0, 44] = 1.0, 2.0, 3.0
    c = coefficients(np.zeros((1, 3)), rest)
    assert c.shape == (1, 16, 3)
    assert c[0, 1].tolist() == [1.0, 2.0, 0.0] and c[0, 15].tolist() == [0.0, 0.0, 3.0]
    assert np.count_nonzero(c) == 3


def test_inria_and_nerfstudio_camera_files_see_the_same_view(tmp_path):
    # a camera at (0, 0, −3) looking along +z with y down (OpenCV), as INRIA's cameras.json stores it
    inria = [{"id": 0, "img_name": "a", "width": 40, "height": 30, "position": [0.0, 0.0, -3.0],
              "rotation": np.eye(3).tolist(), "fx": 35.0, "fy": 35.0}]
    (tmp_path / "cameras.json").write_text(json.dumps(inria))
    # the same camera in nerfstudio's OpenGL axes (y up, z back): camera-to-world columns x, −y, −z
    c2w = np.eye(4)
    c2w[:3, 1] *= -1
    c2w[:3, 2] *= -1
    c2w[:3, 3] = [0, 0, -3.0]
    ns = {"fl_x": 35.0, "fl_y": 35.0, "cx": 20.0, "cy": 15.0, "w": 40, "h": 30,
          "frames": [{"file_path": "images/a.png", "transform_matrix": c2w.tolist()}]}
    (tmp_path / "transforms.json").write_text(json.dumps(ns))
    a, = read_cameras(tmp_path / "cameras.json")
    b, = read_cameras(tmp_path / "transforms.json")
    np.testing.assert_allclose(a.centre, [0, 0, -3.0])
    np.testing.assert_allclose(b.R, a.R, atol=1e-12)
    np.testing.assert_allclose(b.t, a.t, atol=1e-12)
    # world +x is screen right and world +y screen down (OpenCV), the origin at the image centre
    sh = np.zeros((2, 1, 3))
    sh[0, 0] = [1.5, -1.5, -1.5]  # red at the origin
    sh[1, 0] = [-1.5, -1.5, 1.5]  # blue at +x, +y
    g = gaussians([[0, 0, 0], [0.8, 0.6, 0]], [[0.15] * 3] * 2, [[1.0, 0, 0, 0]] * 2, [1.0, 1.0], sh)
    image = render(g, a, background=BLACK).numpy()
    assert image[15, 20, 0] > 0.8 and image[15, 20, 2] < 0.1
    col, row = 35 * 0.8 / 3 + 20, 35 * 0.6 / 3 + 15
    assert image[int(row), int(col), 2] > 0.8
    np.testing.assert_array_equal(render(g, b, background=BLACK).numpy(), image)


def test_bad_camera_file_is_a_one_line_input_error(tmp_path):
    from pixie_gs.errors import InputError

    bad = tmp_path / "cameras.json"
    bad.write_text('{"not": "cameras"}')
    with pytest.raises(InputError, match="cameras.json"):
        read_cameras(bad)
    bad.write_text("[{\"width\": 10}]")
    with pytest.raises(InputError, match="INRIA"):
        read_cameras(bad)


def test_orbit_camera_frames_the_object_with_up_on_top():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(2000, 3)) * [0.2, 0.3, 1.0] + [5.0, -2.0, 1.0]
    points[:5] += 100.0  # floaters do not shrink the object
    for cam in orbit_cameras(points, 8, 64, 48, up="z"):
        p = points[5:] @ cam.R.T + cam.t
        u = cam.fx * p[:, 0] / p[:, 2] + cam.cx
        v = cam.fy * p[:, 1] / p[:, 2] + cam.cy
        inside = (u > 0) & (u < 64) & (v > 0) & (v < 48)
        assert inside.mean() > 0.99 and (v.max() - v.min()) > 0.5 * 48  # framed, and not tiny
        top, bottom = np.argmax(points[5:, 2]), np.argmin(points[5:, 2])
        assert v[top] < v[bottom]  # +z is drawn above −z
    # y up: the highest-y point is drawn near the top
    cam, = orbit_cameras(points[:, [0, 2, 1]], 1, 64, 64, up="y")
    p = points[5:, [0, 2, 1]] @ cam.R.T + cam.t
    v = cam.fy * p[:, 1] / p[:, 2] + cam.cy
    assert v[np.argmax(points[5:, 2])] < 20


def test_modes_render_material_and_log_e_colours():
    from pixie_gs import viz

    cloud = SplatCloud.from_arrays(np.array([[0.0, 0, 0]]), log_scales=np.full((1, 3), np.log(1.0), np.float32),
                                   opacity_logits=np.full(1, 20.0, np.float32), rgb=np.array([[0.2, 0.3, 0.4]]))
    cloud.set_materials(np.array([2]), np.array([1e6]), np.array([0.3]), np.array([1000.0]))
    cam = look_at([0, -3, 0], [0, 0, 0], [0, 0, 1], 24, 24)
    colour, material, log_e = render_modes(cloud, cam, ["colour", "material", "logE"], background=BLACK)
    np.testing.assert_allclose(colour[12, 12] / 255, 0.99 * np.array([0.2, 0.3, 0.4]), atol=1 / 255)
    np.testing.assert_allclose(material[12, 12] / 255, 0.99 * viz.material_colors(np.array([2]))[0], atol=1 / 255)
    np.testing.assert_allclose(log_e[12, 12] / 255, 0.99 * viz.log_e_colors(np.array([1e6]))[0], atol=1 / 255)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (run on a GPU machine)")
@pytest.mark.parametrize("backend", ["warp", "torch"])
def test_cuda_renderer_matches_reference_and_cpu(backend):
    means, scales, quats, opacities, sh = random_scene(0, 70)
    cam = look_at([1.8, -1.4, 0.9], [0, 0, 0], [0, 0, 1], 48, 40, fov_y_deg=50)
    ref = np.clip(reference_render(means, scales, quats, opacities, sh, cam), 0, 1)
    g = gaussians(means, scales, quats, opacities, sh)
    cpu = render(g, cam, backend=backend).numpy()
    g_cuda = Gaussians(*(t.cuda() for t in (g.means, g.scales, g.quats, g.opacities, g.sh)))
    gpu = render(g_cuda, cam, backend=backend).cpu().numpy()
    assert np.abs(gpu - ref).mean() < 1 / 255
    assert np.abs(gpu - cpu).max() < 2 / 255
