"""Up of generated objects under random rotations (TEST seeds, never trained on), judged by a
symmetry-aware error that geometry decides (tests/upright_match.py), and that judge itself on
analytic shapes."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from pixie_gs.convert import mesh_to_splat
from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.generate import object_seed
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.prepare import prepare_cloud
from pixie_gs.prepare.upright import FEATURES, candidates, load_scorer, score
from pixie_gs.splat import SplatCloud
from upright_match import angle_deg, distance_over_floor, law_error, symmetric_error

OBJECTS = 20
GAUSSIANS = 5000


def turned(cloud, R: np.ndarray):
    out = cloud.copy()
    out.means = (cloud.means.astype(np.float64) @ R.T).astype(np.float32)
    out.set_covariances(R @ cloud.covariances() @ R.T)
    return out


# ------------------------------------------------------------------------------------ the judge
@pytest.mark.parametrize("shape, up, same", [
    ("sphere", [1.0, 0.0, 0.0], True), ("sphere", [0.3, -0.5, 0.8], True),
    ("cube", [0.0, 1.0, 0.0], True), ("cube", [0.0, 0.0, -1.0], True), ("cube", [0.3, 0.2, 0.93], False),
    ("box", [1.0, 0.0, 0.0], False), ("box", [0.0, 0.0, -1.0], True),
    ("cone", [0.0, 0.0, -1.0], False), ("cone", [1.0, 0.0, 0.0], False)])
def test_symmetry_judge_on_analytic_shapes(shape, up, same):
    """A sphere is the same from any side, a cube from its six faces, a 0.5 × 0.4 × 0.3 box only
    upside down (a half turn), a cone never: analytic answers, not the code under test."""
    mesh = {"sphere": trimesh.creation.icosphere(3, 0.2), "cube": trimesh.creation.box([0.4, 0.4, 0.4]),
            "box": trimesh.creation.box([0.5, 0.4, 0.3]), "cone": trimesh.creation.cone(0.2, 0.4)}[shape]
    cloud = mesh_to_splat(mesh, 4000, np.random.default_rng(0))
    labels = np.zeros(len(cloud), np.int32)
    _, counted = symmetric_error(cloud.means, labels, np.asarray(up), np.array([0.0, 0.0, 1.0]))
    assert counted == same
    assert max(distance_over_floor(cloud.means, labels, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]))) \
        < 1.01  # the truth against itself is the floor (the best turn found may differ from 0 by ≤ 0.1°)


@pytest.mark.parametrize("shape, expected", [("box", 7.0), ("cone", 173.0)])
def test_a_symmetric_equivalent_off_by_a_small_tilt_counts_the_tilt(shape, expected):
    """Upside down and tilted 7°: a 0.5 × 0.4 × 0.3 box is the same box upside down, so the error is the
    7° tilt; a cone has no such symmetry, so it stays 173° (analytic answers)."""
    mesh = {"box": trimesh.creation.box([0.5, 0.4, 0.3]), "cone": trimesh.creation.cone(0.2, 0.4)}[shape]
    cloud = mesh_to_splat(mesh, 4000, np.random.default_rng(0))
    labels = np.zeros(len(cloud), np.int32)
    est = Rotation.from_euler("x", 7.0, degrees=True).apply([0.0, 0.0, -1.0])
    error, _ = symmetric_error(cloud.means, labels, est, np.array([0.0, 0.0, 1.0]))
    assert error == pytest.approx(expected, abs=0.01)


def test_part_labels_break_a_symmetry():
    """Two halves of a sphere with different part labels: upside down is no longer the same."""
    cloud = mesh_to_splat(trimesh.creation.icosphere(3, 0.2), 4000, np.random.default_rng(1))
    labels = (cloud.means[:, 2] > 0).astype(np.int32)
    assert symmetric_error(cloud.means, labels, np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0]))[1] is False
    assert symmetric_error(cloud.means, labels, np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))[1] is False


def test_an_equal_law_up_counts_only_where_declared():
    """A 0.5 × 0.4 × 0.3 box with +x declared an equal-law up: an estimate 7° off +x is 7° off (an
    equal-law up used); one along +y (not declared, not a symmetry) stays 90° off; with nothing
    declared, +x is 90° off too."""
    cloud = mesh_to_splat(trimesh.creation.box([0.5, 0.4, 0.3]), 4000, np.random.default_rng(0))
    labels = np.zeros(len(cloud), np.int32)
    z, x = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    near_x = Rotation.from_euler("y", -7.0, degrees=True).apply(x)
    error, used = law_error(cloud.means, labels, near_x, z, [x])
    assert used and error == pytest.approx(7.0, abs=0.01)
    error, used = law_error(cloud.means, labels, np.array([0.0, 1.0, 0.0]), z, [x])
    assert not used and error == pytest.approx(90.0, abs=0.01)
    assert law_error(cloud.means, labels, near_x, z, [])[0] == pytest.approx(angle_deg(near_x, z), abs=0.01)


# ------------------------------------------------------------------------------- the estimate
def test_scorer_file_matches_the_code():
    raw = load_scorer()
    assert raw["W1"].shape[-2] == len(FEATURES) and raw["mean"].shape == (len(FEATURES),)
    assert np.isfinite(raw["W1"]).all() and (raw["std"] > 0).all()


def test_an_ensemble_scores_the_mean_of_its_members():
    """upright.score of stacked members equals the mean of each member scored alone."""
    rng = np.random.default_rng(0)
    members = [{"W1": rng.normal(size=(6, 4)), "b1": rng.normal(size=4), "w2": rng.normal(size=4),
                "b2": float(rng.normal())} for _ in range(3)]
    base = {"mean": rng.normal(size=6), "std": rng.uniform(0.5, 2.0, 6)}
    x = rng.normal(size=(9, 6))
    stacked = {**base, **{k: np.stack([np.asarray(m[k]) for m in members]) for k in ("W1", "b1", "w2", "b2")}}
    alone = [np.tanh(((x - base["mean"]) / base["std"]) @ m["W1"] + m["b1"]) @ m["w2"] + m["b2"] for m in members]
    assert np.allclose(score(x, stacked), np.mean(alone, axis=0))
    assert np.allclose(score(x, {**base, **members[0]}), alone[0])


def _views(cloud, ups):
    """Descriptors (dict name → value) of the candidates of `cloud` nearest each of `ups`."""
    cands = candidates(cloud.means.astype(np.float64), cloud.opacities, cloud.rotations, cloud.log_scales, 0.002,
                       colours=cloud.rgb())
    out = []
    for u in ups:
        best = max(cands, key=lambda c: float(c.up @ np.asarray(u)))
        assert float(best.up @ np.asarray(u)) > 0.99
        out.append(dict(zip(FEATURES, best.features)))
    return out


def test_view_features_see_a_stalk_on_top_and_its_contrast():
    """A green ball with a thin brown stalk on top (a fruit): seen upright, the highest 1 % and 3 % of
    its extent are narrow and its highest 5 % differs in colour from the object, the lowest are wider
    and of the object's colour; upside down, the reverse."""
    ball = mesh_to_splat(trimesh.creation.icosphere(3, 0.05), 3000, np.random.default_rng(2),
                         rgb=np.array([0.3, 0.7, 0.2], np.float32), fill=True, n_fill=1000)
    rod = trimesh.creation.cylinder(0.003, 0.02)
    rod.apply_translation([0.0, 0.0, 0.058])
    stalk = mesh_to_splat(rod, 150, np.random.default_rng(3), rgb=np.array([0.4, 0.25, 0.1], np.float32))
    up, down = _views(SplatCloud.concatenate([ball, stalk]), ([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]))
    for view, top, bottom in ((up, "top", "bottom"), (down, "bottom", "top")):  # the stalk's end, the ball's end
        assert view[f"width_{top}1"] < 0.1 < 0.15 < view[f"width_{bottom}1"]  # 3 mm stalk vs a cap of the ball
        assert view[f"width_{top}3"] < 0.1 < 0.3 < view[f"width_{bottom}3"]
        assert view[f"contrast_{top}5"] > 0.2 > 0.05 > view[f"contrast_{bottom}5"]  # brown above, green below


def test_view_features_see_an_open_mouth():
    """A cup (a shell closed at its foot, open at its mouth): the lowest band's outline is covered,
    the highest band is a ring; upside down, the reverse."""
    from pixie_gs.dataset.primitives import lathe

    cup = mesh_to_splat(lathe(np.array([0.04, 0.045, 0.05]), np.array([0.0, 0.05, 0.1]), 32, True, False), 4000,
                        np.random.default_rng(4))
    up, down = _views(cup, ([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]))
    assert up["cover_bottom"] > 1.5 * up["cover_top"] and down["cover_top"] > 1.5 * down["cover_bottom"]


def test_up_of_test_seed_objects_under_random_rotations():
    """20 TEST-seed objects of 20 classes (every third of the 26; seeds the scorer never saw),
    5,000 Gaussians, each under a random rotation: the symmetry-aware error has median ≤ 5° (the
    target) and ≥ 80 % of the objects within 20° (the target is all; benchmarks/bench_prepare.py
    measures 100 objects, docs/benchmarks.md#scene-preparation)."""
    table = load_class_table()
    names = sorted(table)
    errors, raw = [], []
    for i in range(OBJECTS):
        name = names[(3 * i) % len(names)]  # 20 different classes
        cloud, _ = build_object(table[name], object_seed(11, "test", 500 + i), GAUSSIANS)
        R = Rotation.random(random_state=1000 + i).as_matrix()
        moved = turned(cloud, R)
        _, scene = prepare_cloud(moved)
        truth = R @ [0.0, 0.0, 1.0]
        raw.append(angle_deg(scene.up, truth))
        errors.append(symmetric_error(moved.means, moved.get("part_id"), np.asarray(scene.up), truth)[0])
    errors = np.array(errors)
    assert np.median(errors) <= 5.0, (np.round(errors, 1), np.round(raw, 1))
    assert np.mean(errors <= 20.0) >= 0.8, (np.round(errors, 1), np.round(raw, 1))


REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real"


@pytest.mark.skipif(not (REAL / "expectations.json").exists(), reason="../shared/real not present")
@pytest.mark.parametrize("stem", ["Duck", "WaterBottle", "room_vase", "room_plant"])
def test_real_meshes_from_their_shape_alone(stem, tmp_path):
    """The glTF meshes of ../shared/real converted with `pixie convert` defaults, their declared up
    hidden: the scorer, trained on generated objects only, reads each within 20° of the up a person
    reads (expectations.json). A scorer with colour cues of the ends read WaterBottle and room_vase
    on their side (90°, 86°): it had learned the generator's one-colour-per-part palette.
    growing_pla is left out: its 181 m ground plane decides it, not the scorer."""
    import json

    from pixie_gs.cli.main import main
    from pixie_gs.splat import read_splat

    entry = next(e for e in json.loads((REAL / "expectations.json").read_text()) if Path(e["file"]).stem == stem)
    out = tmp_path / f"{stem}.ply"
    assert main(["convert", "-q", str(REAL / "orig" / f"{stem}.glb"), str(out)]) == 0
    cloud = read_splat(out)
    cloud.comments = []
    _, scene = prepare_cloud(cloud)
    assert scene.up_method.startswith("object shape"), scene.up_method
    assert angle_deg(scene.up, entry["up"]) <= 20.0, (stem, scene.up)
