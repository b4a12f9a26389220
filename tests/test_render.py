"""pixie_gs.render: known pixels for known points, occlusion order, sheets and files."""
from __future__ import annotations

import numpy as np
from PIL import Image

from pixie_gs.render import contact_sheet, render_points, save_gif, save_png, view_basis

RED, BLUE, GREEN = [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]


def test_single_red_point_renders_red_at_centre_on_white():
    image = render_points(np.array([[0.3, -0.2, 1.5]]), np.array([RED]), size=(64, 48))
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8
    assert image[24, 32].tolist() == [255, 0, 0]
    red = np.all(image == [255, 0, 0], axis=2)
    assert 1 <= red.sum() <= 25  # a small disc, nothing else drawn
    assert np.all(image[~red] == 255)
    assert image[0, 0].tolist() == [255, 255, 255]


def test_near_point_hides_far_point_in_any_input_order():
    # camera at azimuth 0, elevation 0 with z up looks along −x: larger x is nearer
    near, far = [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]
    box = (np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))
    for means, colours in (([near, far], [RED, BLUE]), ([far, near], [BLUE, RED])):
        image = render_points(np.array(means), np.array(colours), size=(32, 32), azimuth_deg=0,
                              elevation_deg=0, radius_px=3, bounds=box)
        assert image[16, 16].tolist() == [255, 0, 0]
        assert not np.any(np.all(image == [0, 0, 255], axis=2))  # the far disc is fully covered
    # from the opposite side the blue point is the near one
    image = render_points(np.array([near, far]), np.array([RED, BLUE]), size=(32, 32), azimuth_deg=180,
                          elevation_deg=0, radius_px=3, bounds=box)
    assert image[16, 16].tolist() == [0, 0, 255]


def test_view_orientation_and_fit_to_bounds():
    # azimuth 0, elevation 0, z up: +y is screen right, +z is screen up
    np.testing.assert_allclose(view_basis(0, 0, "z"), [[0, 1, 0], [0, 0, 1], [1, 0, 0]], atol=1e-12)
    box = (np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))
    points = np.array([[0, 1.0, 0], [0, 0, 1.0]])
    image = render_points(points, np.array([RED, GREEN]), size=(100, 100), azimuth_deg=0, elevation_deg=0,
                          radius_px=0, bounds=box)
    # the box's half width (1) spans 45 px (5 % margin each side): +y at column 95, +z at row 5
    assert image[50, 95].tolist() == [255, 0, 0]
    assert image[5, 50].tolist() == [0, 255, 0]
    assert (np.any(image != 255, axis=2)).sum() == 2
    # y up: the point at +y is drawn above the centre
    image = render_points(np.array([[0, 1.0, 0]]), np.array([RED]), size=(100, 100), up="y", azimuth_deg=0,
                          elevation_deg=0, radius_px=0, bounds=box)
    assert image[5, 50].tolist() == [255, 0, 0]


def test_per_point_radii_and_many_points():
    means = np.array([[0, -0.5, 0], [0, 0.5, 0]])
    image = render_points(means, np.array([RED, BLUE]), size=(101, 101), azimuth_deg=0, elevation_deg=0,
                          radius_px=np.array([2.0, 6.0]), bounds=(np.full(3, -1.0), np.full(3, 1.0)))
    red = np.all(image == [255, 0, 0], axis=2).sum()
    blue = np.all(image == [0, 0, 255], axis=2).sum()
    assert red == 13  # lattice points with dx² + dy² ≤ 4
    assert blue == 113  # lattice points with dx² + dy² ≤ 36
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(20000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    image = render_points(sphere, (sphere + 1) / 2, size=(128, 128), azimuth_deg=0, elevation_deg=0)
    ink = np.any(image != 255, axis=2)
    yy, xx = np.mgrid[:128, :128]
    inside_disc = (xx + 0.5 - 64) ** 2 + (yy + 0.5 - 64) ** 2 < (0.9 * 64 * 0.97) ** 2
    # the fitted sphere covers its projected disc (auto radius), and nothing far outside it
    assert ink[inside_disc].mean() > 0.97
    assert not ink[(xx + 0.5 - 64) ** 2 + (yy + 0.5 - 64) ** 2 > (0.95 * 64 + 3) ** 2].any()


def test_contact_sheet_size_and_placement():
    a = np.zeros((20, 30, 3), np.uint8)
    b = np.full((10, 40, 3), 128, np.uint8)
    sheet = contact_sheet([a, b, a], ["first", "second", "third"], columns=2)
    assert sheet.shape == (2 * (20 + 16), 2 * 40, 3) and sheet.dtype == np.uint8
    assert np.all(sheet[16:36, 0:30] == 0)  # first image below its label strip
    assert np.all(sheet[16:26, 40:80] == 128)
    assert np.any(sheet[0:16, 0:40] < 128)  # label text was drawn


def test_png_and_gif_files(tmp_path):
    frame = render_points(np.zeros((1, 3)), np.array([RED]), size=(16, 16))
    save_png(frame, tmp_path / "a.png")
    assert np.array_equal(np.asarray(Image.open(tmp_path / "a.png").convert("RGB")), frame)
    frames = [np.full((8, 8, 3), v, np.uint8) for v in (0, 128, 255)]
    save_gif(frames, tmp_path / "a.gif", fps=5)
    with Image.open(tmp_path / "a.gif") as gif:
        assert gif.n_frames == 3
        assert gif.info["duration"] == 200
        gif.seek(1)
        assert np.asarray(gif.convert("RGB"))[0, 0].tolist() == [128, 128, 128]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.png"]
