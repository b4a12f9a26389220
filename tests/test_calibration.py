"""Issue 12 confidence: the calibration measurement (scripts/calibration_diagram.py) checked on known
answers, and the per-Gaussian confidence shown as a view in the rerun recordings pixie writes."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from file_modules import load_file_module
from pixie_gs import viz
from pixie_gs.splat import SplatCloud


def _script():
    """scripts/calibration_diagram.py as a module (registered, as its dataclass needs)."""
    if "calibration_diagram" not in sys.modules:
        load_file_module(Path("scripts/calibration_diagram.py"), "calibration_diagram")
    return sys.modules["calibration_diagram"]


def test_reliability_bins_and_ece_by_hand():
    cal = _script()
    # bin 0.2–0.3: four at 0.25, one right → acc 0.25, gap 0; bin 0.9–1.0: six at 0.95, three right → gap 0.45
    conf = np.array([0.25] * 4 + [0.95] * 6)
    ok = np.array([1, 0, 0, 0, 1, 1, 1, 0, 0, 0], bool)
    rel = cal.reliability(conf, ok)
    assert rel["count"][2] == 4 and rel["count"][9] == 6 and sum(rel["count"]) == 10
    assert rel["accuracy"][2] == pytest.approx(0.25) and rel["accuracy"][9] == pytest.approx(0.5)
    assert rel["ece"] == pytest.approx(0.6 * 0.45) and rel["mce"] == pytest.approx(0.45)
    assert cal.reliability(np.array([1.0, 0.0]), np.array([True, False]))["ece"] == pytest.approx(0.0)  # edges


def test_temperature_fit_recovers_the_temperature_that_made_the_labels():
    """Labels drawn from softmax(z / 2.5): the likelihood fit must find T ≈ 2.5, and dividing by it must
    calibrate confidences that were overconfident at T = 1."""
    cal = _script()
    rng = np.random.default_rng(0)
    z = rng.normal(0, 4, (40_000, 7))
    p = np.exp(z / 2.5 - (z / 2.5).max(1, keepdims=True))
    p /= p.sum(1, keepdims=True)
    true = (p.cumsum(1) > rng.random((len(z), 1))).argmax(1)
    outs = [cal.Outputs(z, true, 1.0, "synthetic")]
    T = cal.fit_temperature(outs)
    assert T == pytest.approx(2.5, rel=0.05)
    before = cal.reliability(*cal.confidence_and_correct(outs))
    after = cal.reliability(*cal.confidence_and_correct(outs, T))
    assert before["ece"] > 0.1 and after["ece"] < 0.02


def test_logistic_map_recovers_a_known_link():
    """Correct with probability exactly p_max whatever the in-distribution factor: the fitted map must be
    the identity on logit p (a ≈ 1, b ≈ 0, c ≈ 0) and bring the ECE of the ind-scaled confidence down."""
    cal = _script()
    rng = np.random.default_rng(2)
    outs = []
    for _ in range(20):
        z = rng.normal(0, 3, (2000, 7))
        p = np.exp(z - z.max(1, keepdims=True))
        p /= p.sum(1, keepdims=True)
        right = rng.random(len(z)) < p.max(1)
        true = np.where(right, p.argmax(1), (p.argmax(1) + 1) % 7)
        outs.append(cal.Outputs(z, true, float(rng.uniform(0.01, 1.0)), "synthetic"))
    a, b, c = cal.fit_logistic(outs)
    assert a == pytest.approx(1.0, abs=0.05) and abs(b) < 0.05 and abs(c) < 0.05
    before = cal.reliability(*cal.confidence_and_correct(outs))["ece"]
    after = cal.reliability(*cal.logistic_confidence(outs, np.array([a, b, c])))["ece"]
    assert before > 0.2 and after < 0.02


def test_script_confidence_is_what_annotate_writes():
    """The diagram scores the confidence users get: same classes and confidence as `annotate_cloud`."""
    from pixie_gs.annotate import annotate_cloud
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.model.checkpoint import load_checkpoint

    cal = _script()
    cloud, _ = build_object(load_class_table()["tree"], object_seed(5, "test", 0), 4000)
    outs = cal.object_outputs(load_checkpoint(None, "cpu"), cloud, "tree")
    conf, ok = cal.confidence_and_correct([outs])
    annotated = annotate_cloud(cloud, None, "cpu")
    np.testing.assert_allclose(conf, annotated.get("confidence"), atol=1e-5)
    np.testing.assert_array_equal(ok, annotated.get("material_id") == cloud.get("material_id"))


def _logged_colours(rrd: Path, entity: str) -> np.ndarray:
    from rerun.chunk import RrdReader

    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        if chunk.entity_path == "/" + entity:
            batch = chunk.to_record_batch()
            if "Points3D:colors" in batch.schema.names:
                cell = batch.column("Points3D:colors")[0]
                packed = np.asarray(cell.values.to_numpy(zero_copy_only=False), np.uint32)  # 0xRRGGBBAA
                return np.stack([(packed >> s) & 0xFF for s in (24, 16, 8)], 1).astype(np.float64) / 255.0
    raise AssertionError(f"no colours logged for {entity}")


def test_recording_has_a_confidence_view_coloured_by_confidence(tmp_path):
    """Read back from the .rrd: a fourth entity `splat/confidence`, shown in the layout, whose colours
    follow the magma map (dark at 0, pale yellow at 1: matplotlib's published end colours)."""
    n = 50
    rng = np.random.default_rng(1)
    cloud = SplatCloud.from_arrays(rng.random((n, 3)), rgb=rng.random((n, 3)))
    cloud.set_materials(np.zeros(n, np.int32), np.full(n, 1e5), np.full(n, 0.3), np.full(n, 900.0))
    conf = np.linspace(0, 1, n).astype(np.float32)
    cloud.set("confidence", conf)
    with viz.recording("pixie-test", rrd_path=tmp_path / "c.rrd") as rec:
        entities = viz.log_material_views(rec, cloud, time_s=0.0)
        viz.log_positions(rec, entities, cloud.means + np.float32(0.5), time_s=0.1)
        viz.send_layout(rec)
    assert entities == viz.MATERIAL_VIEW_ENTITIES and "splat/confidence" in entities
    counts = viz.read_recording_entities(tmp_path / "c.rrd")
    assert counts.get("/splat/confidence", 0) >= 2  # the first frame and the move
    rows = viz.read_recording_positions(tmp_path / "c.rrd", "splat/confidence")
    np.testing.assert_allclose(rows[-1][1], cloud.means + np.float32(0.5), atol=1e-6)
    colours = _logged_colours(tmp_path / "c.rrd", "splat/confidence")
    np.testing.assert_allclose(colours[0], [0.001, 0.000, 0.014], atol=2 / 255)  # magma(0)
    np.testing.assert_allclose(colours[-1], [0.987, 0.991, 0.749], atol=2 / 255)  # magma(1)
    assert np.all(np.diff(colours.sum(1)) > -1e-9)  # brighter with confidence

    plain = SplatCloud.from_arrays(rng.random((n, 3)))
    with viz.recording("pixie-test", rrd_path=tmp_path / "p.rrd") as rec:
        viz.log_material_views(rec, plain)
    np.testing.assert_allclose(_logged_colours(tmp_path / "p.rrd", "splat/confidence"), 0.5, atol=1 / 255)  # grey


def test_annotate_cli_recording_shows_confidence(tmp_path):
    from pixie_gs.cli.main import main
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.splat import read_splat, write_splat

    cloud, _ = build_object(load_class_table()["soda_cans"], object_seed(5, "test", 6), 3000)
    src = tmp_path / "can.ply"
    write_splat(cloud, src)
    rrd = tmp_path / "can.rrd"
    assert main(["annotate", str(src), str(tmp_path / "o.ply"), "--rrd", str(rrd), "--device", "cpu", "-q",
                 "--no-prepare"]) == 0  # the recording is the same on the prepared path (cmd_annotate.py)
    assert viz.read_recording_entities(rrd).get("/splat/confidence", 0) >= 1
    written = read_splat(tmp_path / "o.ply").get("confidence")
    colours = _logged_colours(rrd, "splat/confidence")
    np.testing.assert_allclose(colours, viz.confidence_colors(written), atol=1 / 255 + 1e-6)
