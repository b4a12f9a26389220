"""pixie_gs.lsq.bounded_lstsq: the box-constrained least-squares optimum, checked against SciPy's
lsq_linear (an independent iterative solver) and against answers known in closed form."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from pixie_gs.lsq import MAX_UNKNOWNS, bounded_lstsq


def cost(A: np.ndarray, b: np.ndarray, x: np.ndarray) -> float:
    r = A @ x - b
    return float(r @ r)


def cut_box(rng: np.random.Generator, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box containing 0 that cuts the unbounded solution on some axes (or none), as in fit.predict_linear."""
    n = A.shape[1]
    x_free = np.linalg.lstsq(A, b, rcond=None)[0]
    lo = np.minimum(x_free * rng.uniform(-0.5, 1.5, size=n), 0.0) - rng.uniform(0, 0.1, size=n)
    hi = np.maximum(x_free * rng.uniform(-0.5, 1.5, size=n), 0.0) + 1e-12
    return lo, hi


def assert_same_optimum(A: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray, unique: bool) -> np.ndarray:
    x = bounded_lstsq(A, b, lo, hi)
    assert x.shape == (A.shape[1],)
    assert np.all(x >= lo) and np.all(x <= hi)
    ref = lsq_linear(A, b, bounds=(lo, hi), method="bvls").x
    ours, theirs = cost(A, b, x), cost(A, b, ref)
    # the cost to 1e-12 relative; where the optimum fits b to rounding (cost ~ ε²‖b‖²) to that scale
    assert abs(ours - theirs) <= 1e-12 * max(theirs, 1e-10 * float(b @ b)), (ours, theirs)
    if unique:
        assert np.allclose(x, ref, rtol=1e-9, atol=1e-9 * max(1.0, float(np.abs(ref).max())))
    return x


@pytest.mark.parametrize("seed", range(60))
def test_well_conditioned_matches_scipy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 1 + seed % 3
    m = int(rng.integers(n, 40))
    A = rng.normal(size=(m, n)) * rng.uniform(0.01, 100.0, size=n)
    b = rng.normal(size=m) * 10.0
    lo, hi = cut_box(rng, A, b)
    assert_same_optimum(A, b, lo, hi, unique=True)


@pytest.mark.parametrize("seed", range(60))
def test_square_triangle_as_in_fit_matches_scipy(seed: int) -> None:
    """fit.predict_linear's shape: R (k, k) of J = QR, b = Qᵀr, a box about 0 the optimum leaves."""
    rng = np.random.default_rng(1000 + seed)
    k = 1 + seed % 3
    J = rng.normal(size=(200, k)) * rng.uniform(0.01, 10.0, size=k)
    Q, R = np.linalg.qr(J)
    b = Q.T @ (rng.normal(size=200) * 5.0)
    x_free = np.linalg.solve(R, b)
    lo = -np.abs(x_free) * rng.uniform(0.1, 0.9, size=k)       # the unbounded optimum is outside on every
    hi = np.abs(x_free) * rng.uniform(0.1, 0.9, size=k) + 1e-12  # axis where it cuts
    x = assert_same_optimum(R, b, lo, hi, unique=True)
    assert not np.allclose(x, x_free)


@pytest.mark.parametrize("seed", range(30))
def test_up_to_max_unknowns_matches_scipy(seed: int) -> None:
    rng = np.random.default_rng(2000 + seed)
    n = 4 + seed % (MAX_UNKNOWNS - 3)
    A = rng.normal(size=(n + 5, n))
    b = rng.normal(size=n + 5) * 3.0
    assert_same_optimum(A, b, -0.2 * rng.uniform(0.5, 1, n), 0.2 * rng.uniform(0.5, 1, n), unique=True)


@pytest.mark.parametrize("seed", range(30))
def test_rank_deficient_cost_matches_scipy_and_is_min_norm(seed: int) -> None:
    """Collinear columns: many optima; the cost is SciPy's and x is the smallest of them."""
    rng = np.random.default_rng(3000 + seed)
    n = 2 + seed % 2
    m = 12
    A = rng.normal(size=(m, n))
    A[:, -1] = A[:, 0] * rng.choice([-2.0, 0.5, 1.0])   # last column a multiple of the first
    zero_columns = seed % 5 == 0
    if zero_columns:                                     # or two columns of zeros
        A[:, 0] = 0.0
        A[:, -1] = 0.0
    b = rng.normal(size=m) * 3.0
    lo, hi = cut_box(rng, A, b)
    x = assert_same_optimum(A, b, lo, hi, unique=False)
    # the optima are the box's points with the same A·x: x + t·d along the null vector d (or any
    # value of an unseen unknown); the smallest of them, in closed form
    if zero_columns:
        smallest = x.copy()
        smallest[[0, -1]] = np.clip(0.0, lo[[0, -1]], hi[[0, -1]])
    else:
        d = np.zeros(n)
        d[0], d[-1] = A[0, -1] / A[0, 0], -1.0
        assert np.allclose(A @ d, 0.0, atol=1e-12)
        with np.errstate(divide="ignore", invalid="ignore"):
            ends = np.stack([(lo - x) / d, (hi - x) / d])
        t_lo = np.max(np.where(d != 0, ends.min(axis=0), -np.inf))
        t_hi = np.min(np.where(d != 0, ends.max(axis=0), np.inf))
        smallest = x + np.clip(-(x @ d) / (d @ d), t_lo, t_hi) * d
    assert np.allclose(x, smallest, rtol=0, atol=1e-9 * max(1.0, float(np.abs(x).max())))


def test_underdetermined_matches_scipy() -> None:
    rng = np.random.default_rng(4)
    A = rng.normal(size=(2, 3))
    b = np.array([5.0, -4.0])
    assert_same_optimum(A, b, -np.ones(3), np.ones(3), unique=False)


def test_one_dimensional_clamp() -> None:
    # min Σ (a_i x − b_i)² → x* = a·b / a·a = 2.5, clamped to the nearest end of the interval
    a = np.array([[1.0], [2.0], [3.0]])
    b = a[:, 0] * 2.5
    assert bounded_lstsq(a, b, 0.0, 1.0) == pytest.approx([1.0], abs=0)
    assert bounded_lstsq(a, b, 3.0, 7.0) == pytest.approx([3.0], abs=0)
    assert bounded_lstsq(a, b, -1.0, 9.0) == pytest.approx([2.5], rel=1e-15)


def test_box_corner() -> None:
    # A = I: the problem separates, each coordinate is b clamped to its interval
    b = np.array([3.0, -5.0, 0.25])
    x = bounded_lstsq(np.eye(3), b, [-1.0, -2.0, -1.0], [1.0, 2.0, 1.0])
    assert np.array_equal(x, [1.0, -2.0, 0.25])
    # a coupled problem whose optimum is the corner: the gradient points out of the box there
    A = np.array([[2.0, 1.0], [1.0, 3.0], [0.0, 1.0]])
    b = A @ np.array([4.0, 4.0])
    x = bounded_lstsq(A, b, [0.0, 0.0], [1.0, 1.0])
    assert np.array_equal(x, [1.0, 1.0])
    g = A.T @ (A @ x - b)
    assert np.all(g < 0)   # KKT at the upper corner: the cost falls only by leaving the box


def test_edge_on_one_bound_other_free() -> None:
    # min (x - 3)² + (y + 0.5)² on [0, 1] × [-1, 1] → (1, -0.5)
    x = bounded_lstsq(np.eye(2), np.array([3.0, -0.5]), [0.0, -1.0], [1.0, 1.0])
    assert np.allclose(x, [1.0, -0.5], rtol=0, atol=1e-15)


def test_feasible_unbounded_solution_is_returned() -> None:
    A = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    b = np.array([1.0, 2.0, 2.0])
    x = bounded_lstsq(A, b, [-10.0, -10.0], [10.0, 10.0])
    assert np.allclose(x, np.linalg.lstsq(A, b, rcond=None)[0], rtol=1e-14, atol=0)


def test_column_the_data_cannot_see_stays_at_zero() -> None:
    # the second unknown has no effect: every value of it is optimal, the minimum-norm one is 0
    A = np.array([[1.0, 0.0], [2.0, 0.0]])
    b = np.array([10.0, 20.0])
    assert np.array_equal(bounded_lstsq(A, b, [-1.0, -3.0], [1.0, 3.0]), [1.0, 0.0])
    # when 0 is outside its interval it rests on the bound nearest 0
    assert np.array_equal(bounded_lstsq(A, b, [-1.0, 0.5], [1.0, 3.0]), [1.0, 0.5])


def test_infinite_and_equal_bounds() -> None:
    A = np.array([[1.0, 1.0], [1.0, -1.0], [0.0, 1.0]])
    b = np.array([2.0, 0.0, 5.0])
    ref = lsq_linear(A, b, bounds=([-np.inf, 0.0], [0.5, np.inf]), method="bvls").x
    x = bounded_lstsq(A, b, [-np.inf, 0.0], [0.5, np.inf])
    assert np.allclose(x, ref, rtol=1e-12, atol=1e-12) and x[0] == 0.5
    x = bounded_lstsq(A, b, [0.25, -np.inf], [0.25, np.inf])   # the first unknown fixed at 0.25
    assert x[0] == 0.25
    assert x[1] == pytest.approx(np.linalg.lstsq(A[:, 1:], b - 0.25 * A[:, 0], rcond=None)[0][0], rel=1e-14)


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="lower bound"):
        bounded_lstsq(np.eye(2), np.ones(2), [0.0, 1.0], [1.0, 0.5])
    with pytest.raises(ValueError, match=f"n <= {MAX_UNKNOWNS}"):
        bounded_lstsq(np.eye(MAX_UNKNOWNS + 1), np.ones(MAX_UNKNOWNS + 1), -1.0, 1.0)
    with pytest.raises(ValueError, match="finite"):
        bounded_lstsq(np.array([[np.nan]]), np.ones(1), -1.0, 1.0)
    with pytest.raises(ValueError, match=r"\(m, n\)"):
        bounded_lstsq(np.eye(2), np.ones(3), -1.0, 1.0)
