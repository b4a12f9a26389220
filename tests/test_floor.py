"""Floors under generated objects (`pixie generate --floors`, pixie_gs/dataset/floor.py)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pixie_gs.cli.main import main
from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.floor import FLOOR_PART_ID, floor_under, with_floor
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.dataset.loader import list_objects, load_object
from pixie_gs.model.label_floor import split_floor
from pixie_gs.prepare import ROLE_FLOATER, ROLE_GROUND, prepare_cloud

TABLE = load_class_table()


@pytest.mark.parametrize("name", ["soda_cans", "tree", "books"])
def test_a_floor_is_a_level_disc_under_the_object_labelled_as_ground(name):
    cloud, _ = build_object(TABLE[name], 11, 3000, realistic=True)
    joined, n = with_floor(cloud, np.random.default_rng(2), share=0.25, reach=1.5)
    floor = joined.subset(np.arange(len(cloud), len(joined)))
    assert n == len(floor) == round(0.25 * len(cloud))
    assert np.array_equal(joined.means[:len(cloud)], cloud.means)  # the object keeps its Gaussians and order
    lo, hi = cloud.bounds()
    assert np.allclose(floor.means[:, 2], lo[2])  # level, at the object's lowest centre
    centre, half_diagonal = 0.5 * (lo + hi)[:2], float(np.linalg.norm(hi[:2] - lo[:2])) / 2
    reach = np.linalg.norm(floor.means[:, :2] - centre, axis=1)
    assert reach.max() <= 1.5 * half_diagonal + 1e-6 and reach.max() > 1.3 * half_diagonal
    thin = np.exp(floor.log_scales)
    assert np.allclose(thin[:, 2], thin[:, 0] / 10) and np.allclose(floor.quats, [1, 0, 0, 0])
    assert set(floor.get("material_id")) == {6} and set(floor.get("part_id")) == {FLOOR_PART_ID}
    assert set(floor.get("E")) == {1e9} and set(floor.get("density")) == {1500.0}
    assert floor.sh_degree == cloud.sh_degree and list(floor.extras) == list(cloud.extras)
    assert set(floor.opacity_logits) <= set(cloud.opacity_logits)  # the capture's own opacity law
    # `prepare` finds it as ground (its faintest Gaussians may go as floaters) and it joins no object
    prepared, scene = prepare_cloud(joined, up="z")
    role = prepared.get("role")[len(cloud):]
    assert (role == ROLE_GROUND).mean() > 0.5 and np.isin(role, [ROLE_GROUND, ROLE_FLOATER]).mean() > 0.97
    assert scene.ground_height == pytest.approx(float(lo[2]), abs=0.01 * float((hi - lo).max()))


def test_generate_floors_share_untouched_others_and_label_floor(tmp_path):
    plain, floored = tmp_path / "plain", tmp_path / "floored"
    args = ["--count", "16", "--seed", "7", "--gaussians", "600", "--clean", "--quiet", "--classes", "sport_balls",
            "--split", "test"]
    assert main(["generate", str(plain), *args]) == 0
    assert main(["generate", str(floored), *args, "--floors", "0.5", "--workers", "2"]) == 0
    index = json.loads((floored / "test" / "index.json").read_text())
    with_floors = [e for e in index["objects"] if "floor" in e]
    assert 3 <= len(with_floors) <= 13 and index["floors"] == len(with_floors)
    n_ball = n_floor = 0
    for e in index["objects"]:
        path = floored / "test" / e["file"]
        cloud, record = load_object(path)
        on_floor = cloud.get("part_id") == FLOOR_PART_ID
        if "floor" in e:
            assert on_floor.sum() == e["floor"] == record["floor"]["count"] > 0
            assert record["gaussians"] == len(cloud)
        else:  # an object without a floor is the same file as without --floors
            assert not on_floor.any() and path.read_bytes() == (plain / "test" / e["file"]).read_bytes()
        n_floor += int(on_floor.sum())
        n_ball += int((~on_floor).sum())
    # label floor: the balls' w²/12 (E 3e4–5e4 Pa, ν 0.40–0.45, ρ 80–150 kg/m³, written out), the floor's
    # constant labels add Gaussians with no spread
    def var(width: float, span: float) -> float:
        return (2.0 * width / span) ** 2 / 12.0

    ball = np.array([var(math.log10(5e4 / 3e4), 10.882 - 3.018), var(0.05, 0.449 - 0.210),
                     var(math.log10(150 / 80), 3.871 - 1.703)])
    floor = split_floor(floored, "test")
    assert floor["floor_avg"] == pytest.approx(ball.mean() * n_ball / (n_ball + n_floor), rel=1e-9)


def test_bad_floor_share_is_one_line_with_no_output(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["generate", str(out), "--count", "2", "--gaussians", "300", "--floors", "-0.1", "-q"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--floors must be a share from 0 to 1" in err[0]
    assert not out.exists()


def test_floor_under_a_tiny_cloud_still_has_a_floor():
    cloud, _ = build_object(TABLE["stones"], 3, 200)
    floor = floor_under(cloud, np.random.default_rng(0), share=0.01)
    assert len(floor) == 16 and np.isfinite(floor.means).all()
