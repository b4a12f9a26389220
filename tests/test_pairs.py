"""Pairs of generated objects in one splat (`pixie generate --pairs`, pixie_gs/dataset/pairs.py)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pixie_gs.cli.main import main
from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.dataset.loader import list_objects, load_object
from pixie_gs.dataset.pairs import PARTNER_PART_OFFSET, build_pair, pair_seeds
from pixie_gs.model.label_floor import split_floor
from pixie_gs.splat import SplatCloud, read_splat, sh_dc_to_rgb

TABLE = load_class_table()


def _sh_eval_degree1(cloud: SplatCloud, direction: np.ndarray) -> np.ndarray:
    """RGB seen from `direction` with the real SH basis up to degree 1 (written out: 0.4886 (−y, z, −x))."""
    x, y, z = direction / np.linalg.norm(direction)
    basis = np.array([-0.4886025 * y, 0.4886025 * z, -0.4886025 * x])
    k = cloud.sh_rest.shape[1] // 3
    rest = cloud.sh_rest.reshape(len(cloud), 3, k)[:, :, :3]  # channel-major: R coefficients, then G, then B
    return sh_dc_to_rgb(cloud.sh_dc) + rest @ basis


def test_raising_the_sh_degree_keeps_every_view_and_survives_a_file(tmp_path):
    rng = np.random.default_rng(0)
    one = SplatCloud.from_arrays(rng.normal(size=(50, 3)), sh_rest=rng.normal(0, 0.2, (50, 9)))
    three = one.with_sh_degree(3)
    assert three.sh_degree == 3 and three.sh_rest.shape == (50, 45)
    for d in (np.array([1.0, 0, 0]), np.array([0.3, -0.5, 0.8])):
        assert np.allclose(_sh_eval_degree1(three, d), _sh_eval_degree1(one, d), atol=1e-6)
    # the new coefficients (degree 2 and 3, every colour channel) are zero
    assert not three.sh_rest.reshape(50, 3, 15)[:, :, 3:].any()
    three.write(tmp_path / "three.ply")
    back = read_splat(tmp_path / "three.ply")
    assert back.sh_degree == 3 and np.array_equal(back.sh_rest, three.sh_rest)
    assert np.array_equal(SplatCloud.from_arrays(np.zeros((2, 3))).with_sh_degree(0).sh_rest, np.zeros((2, 0)))
    with pytest.raises(ValueError, match="cannot lower"):
        three.with_sh_degree(1)


def _footprint_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Gap between two point sets' xy boxes along the line joining their box centres, as a share of the
    smaller box's extent along that line (negative: they overlap)."""
    lo_a, hi_a, lo_b, hi_b = a.min(0), a.max(0), b.min(0), b.max(0)
    d = (0.5 * (lo_b + hi_b) - 0.5 * (lo_a + hi_a))[:2]
    d = d / np.linalg.norm(d)
    half_a = 0.5 * float((hi_a - lo_a)[:2] @ np.abs(d))
    half_b = 0.5 * float((hi_b - lo_b)[:2] @ np.abs(d))
    centre_distance = float(np.linalg.norm((0.5 * (lo_b + hi_b) - 0.5 * (lo_a + hi_a))[:2]))
    return (centre_distance - half_a - half_b) / (2.0 * min(half_a, half_b))


@pytest.mark.parametrize("names,realistic", [(("soda_cans", "ceramic_vases"), False),
                                             (("tree", "cushions"), True), (("sand", "guitars"), True)])
def test_a_pair_is_both_objects_with_their_own_labels_side_by_side(names, realistic):
    spec, partner = TABLE[names[0]], TABLE[names[1]]
    cloud, record = build_pair(spec, partner, 1234, 4000, realistic)
    seed_a, seed_b, _ = pair_seeds(1234)
    a, rec_a = build_object(spec, seed_a, 2000, realistic)
    b, rec_b = build_object(partner, seed_b, 2000, realistic)
    assert len(cloud) == len(a) + len(b) == record["gaussians"]
    first, second = slice(0, len(a)), slice(len(a), None)
    for attr in ("material_id", "E", "nu", "density"):  # each object keeps its own per-Gaussian labels
        assert np.array_equal(cloud.get(attr)[first], a.get(attr))
        assert np.array_equal(cloud.get(attr)[second], b.get(attr))
    assert np.array_equal(cloud.get("part_id")[second], b.get("part_id") + PARTNER_PART_OFFSET)
    assert not set(cloud.get("part_id")[first]) & set(cloud.get("part_id")[second])
    # B is A's partner moved rigidly: same shape, same ground height, footprints touching
    moved = cloud.means[second] - b.means
    assert np.allclose(moved, moved[0], atol=1e-5)
    assert np.allclose(cloud.means[first], a.means)
    assert cloud.means[second][:, 2].min() == pytest.approx(a.means[:, 2].min(), abs=1e-5)
    assert -0.1 - 1e-6 <= _footprint_gap(a.means, cloud.means[second]) <= 0.2 + 1e-6
    assert record["class"] == names[0] and record["partner"]["class"] == names[1]
    assert [p["name"] for p in record["partner"]["parts"]] == [p["name"] for p in rec_b["parts"]]
    assert record["partner"]["shift_m"] == pytest.approx(moved[0], abs=1e-4)
    with pytest.raises(ValueError, match="two categories"):
        build_pair(spec, spec, 1, 4000)


def test_generate_pairs_share_partners_and_untouched_singles(tmp_path):
    plain, mixed = tmp_path / "plain", tmp_path / "mixed"
    args = ["--count", "40", "--seed", "5", "--gaussians", "400", "--clean", "--quiet",
            "--classes", "sport_balls,soda_cans,stones,books"]
    assert main(["generate", str(plain), *args]) == 0
    assert main(["generate", str(mixed), *args, "--pairs", "0.5", "--workers", "2"]) == 0
    index = json.loads((mixed / "train" / "index.json").read_text())
    pairs = [e for e in index["objects"] if "partner" in e]
    assert 10 <= len(pairs) <= 30 and index["pairs"] == len(pairs)  # 0.5 of 40: 20 ± 2.2σ
    assert all(e["partner"] != e["class"] for e in pairs)
    assert len({e["partner"] for e in pairs}) >= 3
    for e in index["objects"]:
        path = mixed / "train" / e["file"]
        if "partner" in e:
            cloud, record = load_object(path)
            assert path.stem.endswith(f"+{e['partner']}") and record["partner"]["class"] == e["partner"]
            n_partner = sum(p["count"] for p in record["partner"]["parts"])
            assert (cloud.get("part_id") >= PARTNER_PART_OFFSET).sum() == n_partner
        else:  # an object that stands alone is the same file as without --pairs
            assert path.read_bytes() == (plain / "train" / e["file"]).read_bytes()
    # the same pairs again with one worker (partners come from the object's own stream)
    again = tmp_path / "again"
    assert main(["generate", str(again), *args, "--pairs", "0.5"]) == 0
    assert [p.name for p in list_objects(again, "train")] == [p.name for p in list_objects(mixed, "train")]
    assert all(p.read_bytes() == (mixed / "train" / p.name).read_bytes() for p in list_objects(again, "train"))


def test_label_floor_of_a_pair_split_counts_both_objects(tmp_path):
    """Sport balls paired with soda cans only: the floor is the Gaussian-weighted mean of the two classes'
    w²/12 (written out from classes.json: balls E 3e4–5e4 Pa, ν 0.40–0.45, ρ 80–150; cans E 5e10–8e10 Pa,
    ν 0.25–0.35, ρ 2,600–2,800 kg/m³), all under the first object's category."""
    data = tmp_path / "data"
    assert main(["generate", str(data), "--count", "2", "--split", "test", "--gaussians", "600", "--clean",
                 "--classes", "sport_balls,soda_cans", "--pairs", "1", "-q"]) == 0
    span_e, span_nu, span_rho = 10.882 - 3.018, 0.449 - 0.210, 3.871 - 1.703

    def var(width: float, span: float) -> float:
        return (2.0 * width / span) ** 2 / 12.0

    ball = np.array([var(math.log10(5e4 / 3e4), span_e), var(0.05, span_nu), var(math.log10(150 / 80), span_rho)])
    can = np.array([var(math.log10(8e10 / 5e10), span_e), var(0.10, span_nu), var(math.log10(2800 / 2600), span_rho)])
    n_ball = n_can = 0
    for path in list_objects(data, "test"):
        cloud, _ = load_object(path)
        is_ball = cloud.get("E") < 1e6
        n_ball += int(is_ball.sum())
        n_can += int((~is_ball).sum())
    expected = (ball * n_ball + can * n_can) / (n_ball + n_can)
    floor = split_floor(data, "test")
    assert floor["floor_log_E"] == pytest.approx(expected[0], rel=1e-9)
    assert floor["floor_nu"] == pytest.approx(expected[1], rel=1e-9)
    assert floor["floor_log_rho"] == pytest.approx(expected[2], rel=1e-9)
    assert sorted(floor["by_object_class"]) == ["soda_cans", "sport_balls"]


def test_bad_pair_options_are_one_line_errors_with_no_output(tmp_path, capsys):
    for extra, message in ((["--pairs", "1.5"], "share from 0 to 1"), (["--pairs", "0.5", "--classes", "stones"],
                           "at least two classes"), (["--pairs", "0.5", "--gaussians", "150"], "--gaussians")):
        out = tmp_path / "out"
        args = ["generate", str(out), "--count", "2", "-q", *extra]
        if "--gaussians" not in extra:
            args += ["--gaussians", "300"]
        assert main(args) != 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0]
        assert not out.exists()
