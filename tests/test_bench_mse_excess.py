"""benchmarks/bench_mse_excess.py's part-averaging oracle, against sums worked out by hand."""
from pathlib import Path

import numpy as np

from file_modules import load_file_module


def test_part_mean_squared_error_averages_within_each_labelled_part():
    bench = load_file_module(Path("benchmarks/bench_mse_excess.py"), "bench_mse_excess")
    # two parts of one class told apart by their labels, and a third with the first's label but another class
    target = np.array([[0.2, 0.5, 0.1], [0.2, 0.5, 0.1], [0.8, 0.3, 0.9], [0.8, 0.3, 0.9], [0.2, 0.5, 0.1]])
    true_class = np.array([0, 0, 0, 0, 1])
    phys = np.array([[0.0, 0.5, 0.1], [0.2, 0.7, 0.1], [0.8, 0.3, 0.5], [0.8, 0.3, 0.9], [0.6, 0.5, 0.1]])
    # part means: (0.1, 0.6, 0.1), (0.8, 0.3, 0.7), (0.6, 0.5, 0.1) for the lone Gaussian of class 1
    expected = 2 * np.array([0.01, 0.01, 0.0]) + 2 * np.array([0.0, 0.0, 0.04]) + np.array([0.16, 0.0, 0.0])
    got = bench.part_mean_squared_error(phys, target, true_class)
    assert np.allclose(got, expected)
    # never above the plain error: a part's mean is its least-squares constant
    assert np.all(got <= ((phys - target) ** 2).sum(0) + 1e-12)


def test_grid_ceiling_is_whole_for_one_material_objects_and_high_for_tools(tmp_path):
    """The voxel targets read back per Gaussian: an object of one material can only come back whole (1.0),
    whatever the grid; a hand tool (steel part and handle) keeps most of its Gaussians' labels."""
    from pixie_gs.cli.main import main

    bench = load_file_module(Path("benchmarks/bench_mse_excess.py"), "bench_mse_excess")
    assert main(["generate", str(tmp_path), "--count", "4", "--split", "test", "--gaussians", "1500",
                 "--classes", "soda_cans,metal_tools", "--seed", "8", "-q"]) == 0
    rows = bench.per_object(None, str(tmp_path), "test")
    single = [r for r in rows if r["category"] == "soda_cans"]
    tools = [r for r in rows if r["category"] == "metal_tools"]
    assert single and tools
    assert all(r["grid_accuracy"] == 1.0 for r in single)
    assert all(0.9 <= r["grid_accuracy"] <= 1.0 for r in tools), [r["grid_accuracy"] for r in tools]
    assert bench.summarise(rows, 2)["grid_accuracy"] >= 0.9
