"""benchmarks/bench_real_set.py's per-check readings (confidence, median log10 E, median density) on a splat whose
values are written by hand, so the expected medians are known without the model."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from file_modules import load_file_module
from pixie_gs.splat import SplatCloud, write_splat


def test_region_readings_take_the_medians_inside_each_check_box(tmp_path: Path):
    """Five Gaussians inside the box [0, 1]³ (E 1e7, 1e8, 1e9, 1e9, 1e10 Pa: median 10^9; density 100…500: median
    300; confidence 0.1…0.5: mean 0.3), two outside with extreme values that must not count; a second check's box
    holds nothing and reads NaN."""
    bench = load_file_module(Path("benchmarks/bench_real_set.py"), "bench_real_set")
    inside = np.array([[0.1, 0.1, 0.1], [0.5, 0.5, 0.5], [0.9, 0.2, 0.3], [0.2, 0.8, 0.4], [1.0, 1.0, 1.0]])
    outside = np.array([[2.0, 2.0, 2.0], [-1.0, 0.5, 0.5]])
    cloud = SplatCloud.from_arrays(np.concatenate([inside, outside]))
    cloud.set("E", np.array([1e7, 1e8, 1e9, 1e9, 1e10, 1e3, 1e12]))
    cloud.set("density", np.array([100, 200, 300, 400, 500, 1, 9000], dtype=float))
    cloud.set("confidence", np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.0, 0.0]))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    write_splat(cloud, out_dir / "thing.ply")
    (tmp_path / "expectations.json").write_text(json.dumps([{"file": "thing.ply", "regions": [
        {"region": "cube", "box": [[0, 0, 0], [1, 1, 1]]},
        {"region": "empty", "box": [[5, 5, 5], [6, 6, 6]]}]}]))
    cube, empty = bench.region_readings(tmp_path, out_dir)["thing.ply"]
    assert cube["log10_E_pa"] == pytest.approx(9.0, abs=1e-5)
    assert cube["density_kg_m3"] == pytest.approx(300.0)
    assert cube["confidence"] == pytest.approx(0.3, abs=1e-6)
    assert all(math.isnan(v) for v in empty.values())
