"""`pixie render`: files, frame directories, formats and one-line errors."""
from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from pixie_gs.cli.main import main
from pixie_gs.splat import SplatCloud


def blob(path, shift=0.0, materials=True):
    rng = np.random.default_rng(0)
    means = rng.normal(scale=[0.2, 0.2, 0.5], size=(400, 3)) + [shift, 0, 0]
    cloud = SplatCloud.from_arrays(means, log_scales=np.full((400, 3), np.log(0.04), np.float32),
                                   rgb=np.tile([0.8, 0.2, 0.1], (400, 1)))
    if materials:
        cloud.set_materials(np.full(400, 1), np.full(400, 1e5), np.full(400, 0.3), np.full(400, 1000.0))
    cloud.write(path)
    return cloud


def test_render_a_file_to_png_shows_the_object(tmp_path, capsys):
    blob(tmp_path / "a.ply")
    assert main(["render", str(tmp_path / "a.ply"), "--out", str(tmp_path / "a.png"), "--size", "64", "-q"]) == 0
    image = np.asarray(Image.open(tmp_path / "a.png").convert("RGB")).astype(int)
    assert image.shape == (64 + 16, 3 * 64, 3)  # colour | material | log10 E under a label strip
    colour = image[16:, :64]
    reddish = (colour[:, :, 0] > 150) & (colour[:, :, 1] < 120)
    assert 0.05 < reddish.mean() < 0.8 and reddish[32, 32]  # the red object, centred, not filling the frame
    assert (colour[2, 2] == 255).all()  # white background


def test_render_orbit_gif_and_frames_dir(tmp_path):
    blob(tmp_path / "a.ply")
    assert main(["render", str(tmp_path / "a.ply"), "--out", str(tmp_path / "o.gif"), "--size", "32",
                 "--frames", "4", "--modes", "colour", "-q"]) == 0
    with Image.open(tmp_path / "o.gif") as gif:
        assert gif.n_frames == 4 and gif.size == (32, 48)
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        blob(frames / f"frame_{k:05d}.ply", shift=0.3 * k)
    assert main(["render", str(frames), "--out", str(tmp_path / "f.gif"), "--size", "32", "--fps", "5", "-q"]) == 0
    with Image.open(tmp_path / "f.gif") as gif:
        assert gif.n_frames == 3 and gif.info["duration"] == 200
        centres = []
        for k in range(3):
            gif.seek(k)
            red = np.asarray(gif.convert("RGB"))[16:, :32, 0] < 250
            centres.append(np.nonzero(red)[1].mean())
    assert centres[0] != centres[2]  # the object moves across a still camera
    assert main(["render", str(frames), "--out", str(tmp_path / "s.png"), "--size", "32", "-q"]) == 0
    assert Image.open(tmp_path / "s.png").size == (3 * 32, 3 * (32 + 16))  # 3 frames × 3 modes


def test_render_mp4_when_ffmpeg_is_available(tmp_path):
    from pixie_gs.gsrender.video import ffmpeg_exe

    if ffmpeg_exe() is None:
        pytest.skip("no ffmpeg (pip install imageio-ffmpeg)")
    blob(tmp_path / "a.ply")
    assert main(["render", str(tmp_path / "a.ply"), "--out", str(tmp_path / "o.mp4"), "--size", "33",
                 "--frames", "3", "--modes", "colour", "-q"]) == 0
    data = (tmp_path / "o.mp4").read_bytes()
    assert data[4:8] == b"ftyp" and len(data) > 500


def test_render_errors_are_one_line_and_leave_nothing(tmp_path, capsys):
    blob(tmp_path / "plain.ply", materials=False)
    cases = [
        (["render", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x.png")], "no such file"),
        (["render", str(tmp_path / "plain.ply"), "--out", str(tmp_path / "x.jpg")], "must end in"),
        (["render", str(tmp_path / "plain.ply"), "--out", str(tmp_path / "x.png"), "--modes", "material"],
         "material_id"),
        (["render", str(tmp_path / "plain.ply"), "--out", str(tmp_path / "x.png"), "--modes", "bogus"], "unknown mode"),
        (["render", str(tmp_path), "--out", str(tmp_path / "x.png")], "frame_"),
        (["render", str(tmp_path / "plain.ply"), "--out", str(tmp_path / "nodir" / "x.png")], "does not exist"),
    ]
    for argv, message in cases:
        capsys.readouterr()
        assert main(argv + ["-q"]) == 1
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.ply"]


def test_simulate_render_writes_a_splat_animation(tmp_path):
    blob(tmp_path / "a.ply")
    out = tmp_path / "sim"
    assert main(["simulate", str(tmp_path / "a.ply"), "--out", str(out), "--frames", "3", "--fps", "30",
                 "--no-prepare", "--device", "cpu", "--render", str(tmp_path / "run.gif"), "-q"]) == 0
    with Image.open(tmp_path / "run.gif") as gif:
        assert gif.n_frames == 3 and gif.size == (3 * 320, 320 + 16)
        first = np.asarray(gif.convert("RGB"))[16:, :320]
    assert ((first[:, :, 0] > 150) & (first[:, :, 1] < 120)).any()  # the red blob is drawn
    assert main(["simulate", str(tmp_path / "a.ply"), "--out", str(tmp_path / "sim2"), "--frames", "3",
                 "--no-prepare", "--render", str(tmp_path / "run.jpg"), "-q"]) == 1
    assert not (tmp_path / "sim2").exists()



def test_recording_holds_rendered_pictures_per_frame(tmp_path):
    """What the demo and examples log: one real splat render per frame, in a 2D view of the layout."""
    from pixie_gs import viz
    from pixie_gs.gsrender import orbit_cameras, render_modes

    blob(tmp_path / "a.ply")
    from pixie_gs.splat import read_splat

    cloud = read_splat(tmp_path / "a.ply")
    cam = orbit_cameras(cloud.means, 1, 32, 32)[0]
    rec = viz.open_recording("pixie-test", rrd_path=tmp_path / "run.rrd")
    viz.log_material_views(rec, cloud, time_s=0.0)
    for k in range(3):
        picture, = render_modes(cloud, cam, ["colour"])
        viz.log_image(rec, "render", picture, time_s=0.1 * k)
    viz.send_layout(rec, images=["render"])
    viz.close_recording(rec)
    assert viz.read_recording_entities(tmp_path / "run.rrd").get("/render", 0) == 3
