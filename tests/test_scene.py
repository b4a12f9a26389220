"""Scene JSON: defaults, presets, round trip, and one-line errors naming the file and key."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pixie_gs.errors import InputError
from pixie_gs.sim.scene import BOUNDARY_CELLS, PRESETS, Region, Scene


def write(tmp_path, data) -> str:
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(data))
    return str(path)


def test_defaults_and_grid_geometry():
    scene = Scene.from_dict({"domain": {"size_m": [2.0, 1.0, 0.5], "grid": 40}})
    assert scene.dx == pytest.approx(0.05)
    assert scene.grid_dims == (41, 21, 11)
    assert scene.gravity == (0.0, 0.0, -9.81)
    assert scene.ground.enabled and scene.ground.friction == 0.5 and scene.walls == "slip"
    origin = scene.domain_origin()  # centred on the object in x, y; floor 3 cells under the ground
    assert origin.tolist() == pytest.approx([-1.0, -0.5, -BOUNDARY_CELLS * 0.05])


@pytest.mark.parametrize("name", PRESETS)
def test_presets_load_and_round_trip_through_json(name, tmp_path):
    scene = Scene.preset(name)
    path = tmp_path / f"{name}.json"
    scene.to_json(path)
    again = Scene.from_json(path)
    assert again == scene
    assert json.loads(path.read_text())["gravity"] == [0.0, 0.0, -9.81]


def test_presets_contain_their_effect():
    assert Scene.preset("wind").wind[0].gust_amplitude > 0
    assert Scene.preset("push").impulses[0].velocity_change[0] > 0
    assert Scene.preset("drop").object.position[2] > 0


def test_full_scene_parses_every_key(tmp_path):
    data = {
        "up": "-y", "object": {"size_m": 0.3, "position": [0, 0, 0.1]},
        "domain": {"size_m": 1.5, "grid": 48, "origin": [-0.75, -0.75, -0.1]},
        "gravity": [0, 0, -3.7], "ground": {"enabled": True, "height_m": 0.02, "friction": 0.9},
        "walls": "sticky", "damping": 0.5, "air_drag": 0.1,
        "wind": [{"acceleration": [1, 0, 0], "region": {"min": [0, 0, 0], "max": [1, 1, 1]}, "start_s": 0.5,
                  "end_s": 1.5, "gust_amplitude": 0.3, "gust_frequency_hz": 2.0}],
        "impulses": [{"time_s": 0.2, "velocity_change": [0, 1, 0]}],
        "fixed": [{"region": {"min": [-1, -1, 0], "max": [1, 1, 0.05]}}, {"part_ids": [3, 4]}],
        "part_overrides": {"2": {"E_scale": 0.5, "density_scale": 2.0, "yield_stress_pa": 1e4, "fixed": True}},
        "solver": {"cfl": 0.3, "velocity_cfl": 0.2, "max_substeps_per_frame": 500, "particles_per_cell": 27},
        "materials": {"sand_friction_angle_deg": 35.0, "snow_hardening": 5.0},
    }
    scene = Scene.from_json(write(tmp_path, data))
    assert scene.up == "-y" and scene.walls == "sticky" and scene.air_drag == 0.1
    assert scene.wind[0].end_s == 1.5 and scene.wind[0].region == Region((0, 0, 0), (1, 1, 1))
    assert scene.impulses[0].region is None
    assert scene.fixed[1].part_ids == [3, 4]
    assert scene.part_overrides[2].yield_stress_pa == 1e4 and scene.part_overrides[2].fixed
    assert scene.solver.max_substeps_per_frame == 500 and scene.materials.sand_friction_angle_deg == 35.0
    assert Scene.from_dict(scene.to_dict()) == scene
    assert scene.domain_origin().tolist() == [-0.75, -0.75, -0.1]


@pytest.mark.parametrize("data, message", [
    ({"gravty": [0, 0, -9.8]}, "key 'gravty': unknown key"),
    ({"ground": {"frction": 0.3}}, "key 'ground.frction': unknown key"),
    ({"ground": {"friction": -1}}, "key 'ground.friction': must be ≥ 0"),
    ({"damping": "lots"}, "key 'damping': must be a finite number"),
    ({"gravity": [0, -9.8]}, "key 'gravity': must be a list of 3 finite numbers"),
    ({"walls": "bouncy"}, "key 'walls'"),
    ({"up": "w"}, "key 'up'"),
    ({"domain": {"grid": 4}}, "key 'domain.grid': must be an integer ≥ 8"),
    ({"wind": [{"acceleration": [1, 0, 0], "start_s": 2.0, "end_s": 1.0}]}, "key 'wind[0].end_s'"),
    ({"wind": [{"region": {"min": [0, 0, 0], "max": [1, 1, 1]}}]}, "key 'wind[0]': a wind needs 'acceleration'"),
    ({"impulses": [{"velocity_change": [1, 0, 0], "region": {"min": [1, 0, 0], "max": [0, 1, 1]}}]},
     "key 'impulses[0].region'"),
    ({"fixed": [{}]}, "key 'fixed[0]'"),
    ({"part_overrides": {"leaf": {"E_scale": 2}}}, "key 'part_overrides.leaf'"),
    ({"part_overrides": {"1": {"E_scal": 2}}}, "key 'part_overrides.1.E_scal'"),
    ({"solver": {"cfl": 2.0}}, "key 'solver.cfl': must be ≤ 1"),
    # a subnormal side passed "> 0" and made the grid spacing 0 (divide by zero in grid_dims)
    ({"domain": {"size_m": 5e-324}}, "key 'domain.size_m': must be ≥ 0.001"),
    ({"domain": {"size_m": [1.0, 1.0, 1e-9]}}, "key 'domain.size_m': every side must be ≥ 0.001 m"),
    ({"object": {"size_m": 1e-300}}, "key 'object.size_m': must be ≥ 0.001"),
])
def test_bad_keys_and_values_name_the_file_and_key(tmp_path, data, message):
    path = write(tmp_path, data)
    with pytest.raises(InputError) as info:
        Scene.from_json(path)
    text = str(info.value)
    assert text.startswith(f"{path}: ") and message in text and "\n" not in text


def test_unreadable_or_invalid_json_is_one_line(tmp_path):
    with pytest.raises(InputError, match="cannot read scene file"):
        Scene.from_json(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{ nope")
    with pytest.raises(InputError, match=r"bad\.json: not valid JSON \(line 1"):
        Scene.from_json(bad)
    with pytest.raises(InputError, match="unknown scene preset 'storm'"):
        Scene.preset("storm")


def test_region_contains_faces_included():
    region = Region((0, 0, 0), (1, 1, 1))
    inside = region.contains(np.array([[0, 0, 0], [1, 1, 1], [0.5, 0.5, 1.0001]]))
    assert inside.tolist() == [True, True, False]
