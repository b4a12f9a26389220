"""Every script in examples/ runs at CI size (--tiny) and shows the physics it promises.

The scripts are imported and their `main(argv)` called in this process (the same code path as
`python examples/NAME.py --tiny`, without paying for a fresh interpreter and Warp start-up per
script). Materials are predicted by the shipped checkpoint, as for a user (the default
`--labels predicted`), so each test covers annotate → simulate → outputs on a shipped example.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from file_modules import load_file_module
from pixie_gs.splat import read_splat

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def run_example(name: str, out: Path, *extra: str) -> dict:
    """Import examples/NAME.py and run its main with --tiny; returns the facts it reports."""
    sys.path.insert(0, str(EXAMPLES))
    try:
        module = load_file_module(EXAMPLES / f"{name}.py", f"example_{name}")
        facts = module.main(["--tiny", "--quiet", "--device", "cpu", "--out", str(out), *extra])
    finally:
        sys.path.remove(str(EXAMPLES))
    return facts


def check_outputs(out: Path, frames: int) -> np.lib.npyio.NpzFile:
    """The files every example writes exist and agree with each other."""
    annotated = read_splat(out / "annotated.ply")
    assert annotated.has_materials()
    frame_files = sorted((out / "frames").glob("frame_*.ply"))
    assert len(frame_files) == frames
    tracks = np.load(out / "frames" / "tracks.npz")
    assert tracks["x"].shape[0] == frames and tracks["t"].shape == (frames,)
    last = read_splat(frame_files[-1])
    np.testing.assert_array_equal(last.means, tracks["x"][-1])  # frames and tracks agree
    assert (out / "run.rrd").stat().st_size > 1000
    assert (out / "strip.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / "summary.json").read_text())["frames"] == frames
    return tracks


def test_tree_in_wind_top_moves_downwind_pot_stays(tmp_path):
    facts = run_example("tree_in_wind", tmp_path)
    check_outputs(tmp_path, facts["frames"])
    assert facts["anchored_gaussians"] > 0
    assert facts["anchored_max_motion_m"] == 0.0  # the pot does not move at all
    # wind along +x bends the top: 1.5 % of the height. It was 5 %, set on r30, whose visible trunk read
    # 2e7 Pa (top 7 cm downwind); r36 read it 5e7 Pa (2.5 cm here), r39 3.6e8 Pa (3.6 cm: the crown sways),
    # its label is 3.5e9 Pa, and a trunk at the label would bend millimetres (docs/model_card.md): the
    # motion is the soft crown's and the trunk's, and 1.5 % still fails a gust that does nothing
    assert facts["top_max_downwind_m"] > 0.015 * facts["tree_height_m"]
    # gravity is on: the tree stands under its own weight (the paper's 2e6 Pa trunk sank by ~60 % in 3 s)
    assert facts["top_sink_last_m"] < 0.1 * facts["tree_height_m"]


def test_duck_drop_bounces(tmp_path):
    facts = run_example("duck_drop", tmp_path)
    tracks = check_outputs(tmp_path, facts["frames"])
    # it fell (mean height dropped by most of the 15 cm drop) and touched down before rising again
    assert facts["start_centre_height_m"] - facts["lowest_centre_height_m"] > 0.1
    assert facts["bottom_at_impact_m"] < 0.05
    assert facts["rebound_height_m"] > 0.02
    assert facts["bounced"]
    assert np.isfinite(tracks["x"]).all()


def test_can_impulse_dents_and_stays_dented(tmp_path):
    facts = run_example("can_impulse", tmp_path)
    check_outputs(tmp_path, facts["frames"])
    dent = facts["diameter_before_m"] - facts["diameter_after_m"]
    assert dent > 0.1 * facts["diameter_before_m"]  # wall pushed in by > 10 % of the diameter ...
    # ... and it stays: the last frame is as deep as the deepest, no elastic spring-back
    assert facts["diameter_after_m"] - facts["diameter_min_m"] < 0.1 * dent


def test_sand_pile_spreads(tmp_path):
    facts = run_example("sand_pile", tmp_path)
    check_outputs(tmp_path, facts["frames"])
    assert facts["radius_after_m"] > 1.1 * facts["radius_before_m"]
    assert facts["height_after_m"] < 0.8 * facts["height_before_m"]


def test_snow_lump_squashes(tmp_path):
    facts = run_example("snow_squash", tmp_path)
    check_outputs(tmp_path, facts["frames"])
    assert facts["landed"]
    squash = facts["height_before_m"] - facts["height_min_m"]
    assert facts["height_after_m"] < 0.8 * facts["height_before_m"]  # squashed by > 20 % ...
    assert facts["height_after_m"] - facts["height_min_m"] < 0.25 * squash  # ... and it stays squashed


def test_bring_your_own_mesh_converts_annotates_and_falls(tmp_path):
    facts = run_example("bring_your_own_mesh", tmp_path)
    tracks = check_outputs(tmp_path, facts["frames"])
    converted = read_splat(tmp_path / "converted.ply")
    assert len(converted) == facts["converted_gaussians"] > 4000  # surface + interior fill
    assert not converted.has_materials() and read_splat(tmp_path / "annotated.ply").has_materials()
    assert facts["fell"]  # the `drop` preset: 0.3 m above the ground, it comes down
    assert np.isfinite(tracks["x"]).all()


def test_demo_writes_everything_and_the_tree_sways_with_its_pot_fixed(tmp_path):
    """`pixie demo`'s library entry at a small size: shipped tree + shipped checkpoint."""
    from PIL import Image

    from pixie_gs.demo import DemoSettings, run_demo
    from pixie_gs.viz import MATERIAL_VIEW_ENTITIES, read_recording_entities

    result = run_demo(tmp_path / "demo", DemoSettings(frames=4, particles_per_cell=1, device="cpu"))
    files = result.files
    annotated = read_splat(files["annotated"])
    assert len(annotated) == result.gaussians > result.simulated > 0  # the whole tree is annotated
    assert annotated.has_materials()
    assert result.material_counts.get("stationary", 0) > 0  # the model finds the pot
    assert len(sorted(files["frames"].glob("frame_*.ply"))) == 4
    tracks = np.load(files["frames"] / "tracks.npz")["x"]
    assert tracks.shape == (4, result.gaussians, 3)  # every Gaussian is in the frames, simulated or carried
    np.testing.assert_array_equal(tracks[0], annotated.means)
    pot = annotated.get("material_id") == 6
    np.testing.assert_array_equal(tracks[-1][pot], annotated.means[pot])  # carried pot Gaussians stay put too
    last = read_splat(sorted(files["frames"].glob("frame_*.ply"))[-1])
    np.testing.assert_array_equal(last.means, tracks[-1])
    with Image.open(files["gif"]) as gif:
        assert gif.n_frames == 4
    assert files["strip"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    logged = read_recording_entities(files["rrd"])
    for entity in MATERIAL_VIEW_ENTITIES:  # RGB, material and log E views: frame 0 + 3 moves each
        assert logged.get("/" + entity, 0) >= 4, logged
    assert result.anchored_max_displacement == 0.0  # pot and base do not move
    assert result.top_displacement[-1, 0] > 0.0  # the top moves downwind (+x) ...
    # ... more along the wind than across it (under gravity the off-centre crown also leans a little)
    assert result.top_displacement[-1, 0] > abs(result.top_displacement[-1, 1])


def test_carrier_moves_unsimulated_gaussians_with_their_nearest_particle():
    """Known answer: under a homogeneous F and a translation, carried Gaussians land where the
    same affine motion puts them, and their deformation gradient is the carrier's."""
    from pixie_gs.sim.subsample import Carrier
    from pixie_gs.sim.run import FrameState

    rng = np.random.default_rng(1)
    simulated = rng.uniform(-1, 1, (50, 3)).astype(np.float32)
    everyone = np.concatenate([simulated, simulated[:20] + rng.normal(0, 0.01, (20, 3)).astype(np.float32)])
    F = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 1.2]], np.float32)
    shift = np.array([0.3, -0.2, 0.5], np.float32)
    moved = simulated @ F.T + shift
    state = FrameState(index=1, time_s=0.1, x=moved, x_world=moved, F=np.tile(F, (50, 1, 1)))
    carried = Carrier(everyone, simulated).carry(state)
    np.testing.assert_allclose(carried.x, everyone @ F.T + shift, atol=1e-5)
    np.testing.assert_array_equal(carried.F, np.tile(F, (70, 1, 1)))
    # with materials, a Gaussian rides on the nearest simulated Gaussian of its own material
    near = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], np.float32)
    carrier = Carrier(np.array([[0.1, 0.0, 0.0]], np.float32), near, np.array([1]), np.array([0, 1]))
    assert carrier.anchor.tolist() == [1]


def test_subsample_per_cell_keeps_every_occupied_cell_and_caps_each():
    """Known answer: a dense cluster is thinned to the cap, a sparse line keeps every point."""
    from pixie_gs.sim.subsample import subsample_per_cell
    from pixie_gs.sim.run import placement_transform
    from pixie_gs.sim.scene import Scene
    from pixie_gs.splat import SplatCloud

    rng = np.random.default_rng(0)
    blob = rng.uniform([0.4, 0.4, 0.8], [0.6, 0.6, 1.0], (5000, 3))  # many points per cell
    line = np.stack([np.full(7, 0.5), np.full(7, 0.5), np.linspace(0.0, 0.78, 7)], axis=1)  # 13 cm apart
    cloud = SplatCloud.from_arrays(np.concatenate([blob, line]).astype(np.float32))
    scene = Scene.from_dict({"object": {"size_m": 1.0}, "domain": {"size_m": 2.0, "grid": 20}})  # 10 cm cells
    keep = subsample_per_cell(cloud, scene, 3, seed=1)
    np.testing.assert_array_equal(keep, subsample_per_cell(cloud, scene, 3, seed=1))  # deterministic
    assert not np.array_equal(keep, subsample_per_cell(cloud, scene, 3, seed=2))
    assert np.all(np.isin(np.arange(5000, 5007), keep))  # the thin line (1 point per cell) survives whole
    world = placement_transform(cloud.means, scene).to_world(cloud.means)
    cell = lambda idx: np.floor((world[idx] - scene.domain_origin()) / scene.dx).astype(int)  # noqa: E731
    _, all_counts = np.unique(cell(np.arange(len(cloud))), axis=0, return_counts=True)
    _, kept_counts = np.unique(cell(keep), axis=0, return_counts=True)
    assert kept_counts.max() == 3 and len(kept_counts) == len(all_counts)  # every cell kept, none above 3
