"""The label floor of `pixie evaluate` (pixie_gs/model/label_floor.py), against closed forms and the generator."""
import json
import math

import numpy as np
import pytest

from pixie_gs.dataset.labels import load_class_table, sample_part_values
from pixie_gs.materials import normalize_physical
from pixie_gs.model.label_floor import part_floor, split_floor

# Normalisation spans of the model's targets (materials.py), written out: log10 E 3.018–10.882 Pa,
# ν 0.210–0.449, log10 ρ 1.703–3.871 kg/m³; each maps onto [-1, 1].
SPAN_LOG_E, SPAN_NU, SPAN_LOG_RHO = 10.882 - 3.018, 0.449 - 0.210, 3.871 - 1.703


def _uniform_var(width: float, span: float) -> float:
    return (2.0 * width / span) ** 2 / 12.0


def _generate(tmp_path, classes: str, count: int = 2):
    from pixie_gs.cli.main import main

    data = tmp_path / "data"
    assert main(["generate", str(data), "--count", str(count), "--split", "test", "--gaussians", "300",
                 "--classes", classes, "-q"]) == 0
    return data


def test_floor_of_one_class_is_the_variance_of_its_ranges(tmp_path):
    """Sport balls (E 3e4–5e4 Pa, ν 0.40–0.45, ρ 80–150 kg/m³ in classes.json): w²/12 per quantity."""
    floor = split_floor(_generate(tmp_path, "sport_balls"))
    e = _uniform_var(math.log10(5e4 / 3e4), SPAN_LOG_E)
    nu = _uniform_var(0.05, SPAN_NU)
    rho = _uniform_var(math.log10(150 / 80), SPAN_LOG_RHO)
    assert floor["floor_log_E"] == pytest.approx(e, rel=1e-9)
    assert floor["floor_nu"] == pytest.approx(nu, rel=1e-9)
    assert floor["floor_log_rho"] == pytest.approx(rho, rel=1e-9)
    assert floor["floor_avg"] == pytest.approx((e + nu + rho) / 3, rel=1e-9)
    assert list(floor["by_object_class"]) == ["sport_balls"]


def test_floor_matches_the_spread_of_the_generators_draws():
    """The empirical variance of 3,000 label draws of each part (the generator's own sampler) agrees with
    the floor within 10 %: the floor is the error of predicting the range's middle."""
    table = load_class_table()
    rng = np.random.default_rng(7)
    for name in ("wooden_chairs", "cushions", "soda_cans", "tree"):
        spec = table[name]
        present = [p.name for p in spec.parts]
        draws = {p: [] for p in present}
        for _ in range(3000):
            values, _ = sample_part_values(spec, present, rng)
            for p in present:
                draws[p].append(normalize_physical(values[p]["E"], values[p]["nu"], values[p]["density"]))
        for p in present:
            empirical = np.var(np.array(draws[p], np.float64), axis=0)
            expected = part_floor(spec.part(p))
            # rejection by constraints (tree: leaves.E < trunk.E …) may only narrow a draw, never widen it
            assert np.all(empirical <= expected * 1.1 + 1e-9), (name, p, empirical, expected)
            if not spec.constraints:
                assert empirical == pytest.approx(expected, rel=0.1), (name, p)


def test_no_floor_for_a_dataset_made_with_another_table(tmp_path):
    """A record with a value outside the installed table's range, or an unknown class: None, not a wrong floor."""
    data = _generate(tmp_path, "soda_cans")
    assert split_floor(data) is not None
    record_path = sorted((data / "test").glob("0*.json"))[0]
    record = json.loads(record_path.read_text())
    record["parts"][0]["nu"] = 0.45  # soda cans draw ν in 0.25–0.35
    record_path.write_text(json.dumps(record))
    assert split_floor(data) is None
    record["class"] = "teapots"
    record_path.write_text(json.dumps(record))
    assert split_floor(data) is None


def test_evaluate_prints_and_stores_the_floor(tmp_path, capsys):
    """`pixie evaluate` shows a floor row and per-category floors, and writes them to --json."""
    from pixie_gs.cli.main import main
    from pixie_gs.model.checkpoint import DEFAULT_CHECKPOINT

    data = _generate(tmp_path, "sport_balls,soda_cans", count=2)
    report = tmp_path / "m.json"
    capsys.readouterr()
    assert main(["evaluate", str(DEFAULT_CHECKPOINT), str(data), "--device", "cpu", "--json", str(report), "-q"]) == 0
    table = capsys.readouterr().out
    assert "floor" in table.splitlines()[4] and "best possible prediction" in table
    metrics = json.loads(report.read_text())
    expected = split_floor(data)
    assert metrics["label_floor"] == json.loads(json.dumps(expected))
    for category, value in expected["by_object_class"].items():
        row = next(line for line in table.splitlines() if line.strip().startswith(category))
        assert float(row.split()[-1]) == pytest.approx(value, abs=5e-5)
