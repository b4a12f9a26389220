"""pixie_gs.lsq.bounded_lstsq is SciPy's lsq_linear(method="bvls"), without importing scipy.optimize."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from pixie_gs.lsq import bounded_lstsq


@pytest.mark.parametrize("seed", range(40))
def test_matches_scipy_bvls_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = 1 + seed % 3
    m = int(rng.integers(k, 40))
    A = rng.normal(size=(m, k)) * rng.uniform(0.01, 100.0, size=k)
    b = rng.normal(size=m) * 10.0
    # bounds that cut the unbounded solution on some axes (or none), as in fit.predict_linear
    x_free = np.linalg.lstsq(A, b, rcond=-1)[0]
    lo = np.minimum(x_free * rng.uniform(-0.5, 1.5, size=k), 0.0) - rng.uniform(0, 0.1, size=k)
    hi = np.maximum(x_free * rng.uniform(-0.5, 1.5, size=k), 0.0) + 1e-12
    ours = bounded_lstsq(A, b, lo, hi)
    ref = lsq_linear(A, b, bounds=(lo, hi), method="bvls").x
    assert np.array_equal(ours, ref)
    assert np.all(ours >= lo) and np.all(ours <= hi)


def test_feasible_unbounded_solution_is_returned_as_is() -> None:
    A = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    b = np.array([1.0, 2.0, 2.0])
    x = bounded_lstsq(A, b, [-10.0, -10.0], [10.0, 10.0])
    assert np.array_equal(x, np.linalg.lstsq(A, b, rcond=-1)[0])


def test_active_bound_is_the_constrained_minimum() -> None:
    # min (x - 3)² on [0, 1] → 1; a second free coordinate still solves its own part
    A = np.eye(2)
    x = bounded_lstsq(A, np.array([3.0, -0.5]), [0.0, -1.0], [1.0, 1.0])
    assert np.allclose(x, [1.0, -0.5])


def test_rejects_empty_boxes() -> None:
    with pytest.raises(ValueError):
        bounded_lstsq(np.eye(2), np.ones(2), [0.0, 1.0], [1.0, 1.0])
