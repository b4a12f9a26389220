"""pixie_gs.viz: real .rrd files written by rerun and read back with rerun's own reader."""
from __future__ import annotations

import numpy as np
import pytest

from pixie_gs import viz
from pixie_gs.materials import MATERIAL_COLORS
from pixie_gs.splat import SplatCloud


def _cloud(n: int = 40) -> SplatCloud:
    rng = np.random.default_rng(0)
    cloud = SplatCloud.from_arrays(rng.random((n, 3)), rgb=rng.random((n, 3)))
    cloud.set_materials(rng.integers(0, 7, n), 10 ** rng.uniform(4, 9, n), np.full(n, 0.3), np.full(n, 900.0))
    return cloud


def test_material_views_over_time_round_trip(tmp_path):
    cloud = _cloud()
    target = tmp_path / "run.rrd"
    rec = viz.open_recording("pixie-test", rrd_path=target)
    entities = viz.log_material_views(rec, cloud, time_s=0.0)
    for k in (1, 2):
        viz.log_positions(rec, entities, cloud.means + np.float32(0.25 * k), time_s=0.1 * k)
    viz.log_scalar(rec, "plots/energy", 3.0, time_s=0.1)
    viz.send_layout(rec, plots=["plots"])
    assert not target.exists(), "the .rrd must only appear once the recording is closed"
    assert viz.close_recording(rec) == target
    assert [p.name for p in tmp_path.iterdir()] == ["run.rrd"]  # temporary file renamed away

    counts = viz.read_recording_entities(target)
    assert {"/splat/rgb", "/splat/material", "/splat/log_E", "/splat/material", "/plots/energy"} <= set(counts)
    rows = viz.read_recording_positions(target, "splat/log_E")
    assert [t for t, _ in rows] == pytest.approx([0.0, 0.1, 0.2])
    for k, (_, xyz) in enumerate(rows):
        np.testing.assert_allclose(xyz, cloud.means + np.float32(0.25 * k), atol=1e-6)

    from rerun.chunk import RrdReader
    reader = RrdReader(str(target))
    assert len(reader.blueprints()) == 1  # the layout travels with the recording


def test_material_view_colours(tmp_path):
    cloud = _cloud(7)
    cloud.set("material_id", np.arange(7), np.int32)
    colors = viz.material_colors(cloud.get("material_id"))
    np.testing.assert_array_equal(colors, MATERIAL_COLORS[:7])
    np.testing.assert_array_equal(viz.material_colors(np.array([99, -1])), MATERIAL_COLORS[[7, 7]])
    lo, hi = viz.log_e_colors(np.array([1e3, 1e11]))  # clipped to the dataset range ends
    from matplotlib import colormaps
    np.testing.assert_allclose(lo, colormaps["viridis"](0.0)[:3], atol=1e-6)
    np.testing.assert_allclose(hi, colormaps["viridis"](1.0)[:3], atol=1e-6)


def test_static_log_and_discard(tmp_path):
    cloud = _cloud()
    with viz.recording("pixie-test", rrd_path=tmp_path / "a.rrd") as rec:
        viz.log_splat(rec, "cloud", cloud)  # static: no time
    rows = viz.read_recording_positions(tmp_path / "a.rrd", "cloud")
    assert len(rows) == 1 and rows[0][0] is None
    np.testing.assert_array_equal(rows[0][1], cloud.means)

    with pytest.raises(RuntimeError):
        with viz.recording("pixie-test", rrd_path=tmp_path / "b.rrd") as rec:
            viz.log_splat(rec, "cloud", cloud)
            raise RuntimeError("simulated failure")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.rrd"]  # no partial recording


def test_null_recording_is_silent_no_op(tmp_path):
    rec = viz.open_recording("pixie-test")
    assert not rec.is_enabled()
    viz.log_material_views(rec, _cloud())
    viz.send_layout(rec)
    assert viz.close_recording(rec) is None
    assert list(tmp_path.iterdir()) == []


def test_log_style_is_static_colour_only(tmp_path):
    """Styling moving points must not log static positions (they would shadow the temporal ones)."""
    means = np.zeros((5, 3), np.float32)
    with viz.recording("pixie-test", rrd_path=tmp_path / "s.rrd") as rec:
        viz.log_style(rec, "pts", rgb=(255, 0, 0), radii=0.01)
        for k in range(3):
            viz.log_splat(rec, "pts", means + k, time_s=0.5 * k)
    rows = viz.read_recording_positions(tmp_path / "s.rrd", "pts")
    assert [t for t, _ in rows] == [0.0, 0.5, 1.0]  # no static positions row
    from rerun.chunk import RrdReader
    static = [c for c in RrdReader(str(tmp_path / "s.rrd")).stream().to_chunks()
              if c.entity_path == "/pts" and c.is_static]
    assert static and "Points3D:colors" in static[0].to_record_batch().schema.names


def test_spawn_without_display_is_a_clear_error(tmp_path, monkeypatch):
    import sys

    from pixie_gs.errors import InputError

    if not sys.platform.startswith("linux"):
        pytest.skip("display detection is only done on Linux")
    for key in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(key, raising=False)
    with pytest.raises(InputError, match="display"):
        viz.open_recording("pixie-test", rrd_path=tmp_path / "x.rrd", spawn=True)
    assert list(tmp_path.iterdir()) == []  # the pending .rrd was removed


def test_positions_read_back_at_frame_times_that_are_not_whole_microseconds(tmp_path):
    cloud = _cloud(10)
    target = tmp_path / "fps15.rrd"
    rec = viz.open_recording("pixie-test", rrd_path=target)
    entities = viz.log_material_views(rec, cloud, time_s=0.0)
    viz.log_positions(rec, entities, cloud.means + np.float32(1.0), time_s=1.0 / 15.0)
    viz.close_recording(rec)
    rows = viz.read_recording_positions(target, "splat/rgb")
    assert [t for t, _ in rows] == pytest.approx([0.0, 1.0 / 15.0], abs=1e-9)
    np.testing.assert_allclose(rows[1][1], cloud.means + 1.0, atol=1e-6)
