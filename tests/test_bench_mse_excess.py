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
