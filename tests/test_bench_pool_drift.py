"""benchmarks/bench_pool_drift.py's line, shifts and fixed point, against figures worked out by hand."""
from pathlib import Path

import pytest

from file_modules import load_file_module


def test_drift_finds_a_known_compression_and_its_fixed_point():
    """B = 0.9 · A + 0.7 exactly on four objects: slope 0.9, intercept 0.7, fixed point 0.7 / 0.1 = 7 decades;
    the object at 10 decades (stiff) moves by 0.9·10 + 0.7 − 10 = −0.3, the one at 5 (soft) by +0.2."""
    bench = load_file_module(Path("benchmarks/bench_pool_drift.py"), "bench_pool_drift")
    a = {("s.ply", 0): 5.0, ("t.ply", 0): 7.5, ("u.ply", 0): 8.0, ("v.ply", 0): 10.0, ("only_a.ply", 0): 4.0}
    b = {k: 0.9 * v + 0.7 for k, v in a.items() if k[0] != "only_a.ply"}
    r = bench.drift(a, b)
    assert r["objects"] == 4
    assert r["slope"] == pytest.approx(0.9) and r["intercept"] == pytest.approx(0.7)
    assert r["fixed_point_log10_e"] == pytest.approx(7.0)
    assert r["stiff_objects"] == 1 and r["stiff_shift"] == pytest.approx(-0.3)
    assert r["soft_objects"] == 1 and r["soft_shift"] == pytest.approx(0.2)
    assert r["spread_b"] == pytest.approx(0.9 * r["spread_a"])


def test_drift_of_a_pool_against_itself_has_no_fixed_point():
    bench = load_file_module(Path("benchmarks/bench_pool_drift.py"), "bench_pool_drift")
    a = {("s.ply", 0): 5.0, ("t.ply", 0): 9.0, ("t.ply", 1): 9.5}
    r = bench.drift(a, dict(a))
    assert r["slope"] == pytest.approx(1.0) and r["fixed_point_log10_e"] is None and r["stiff_shift"] == 0.0
