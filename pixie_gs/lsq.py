"""Bounded linear least squares for a few unknowns, without importing scipy.optimize.

Why: diagnose's screening solves min ‖A·x − b‖ subject to lb ≤ x ≤ ub for k ≤ 3 parameters on
a k×k triangle (fit.predict_linear), a microsecond problem; importing scipy.optimize for it costs
~0.35 s of CPU (more on a cold file system), on the critical path of a GPU diagnosis.

How: exact enumeration of the active set. At a minimiser of this convex problem every variable is
strictly inside its interval or on one of its two bounds. Once that "status" of each variable is
guessed, the bounded variables are known and the rest solve an ordinary least-squares problem.
With n unknowns there are 3ⁿ guesses (27 for n = 3); all are tried, the candidates whose free
variables land inside their bounds are kept, and the one with the lowest residual wins. There
is no iteration and no stopping tolerance, so the answer is the optimum to rounding.

Rank-deficient A (collinear columns, a column of zeros, fewer rows than unknowns): the optimum
is then a set, not a point. Each free sub-problem is solved with numpy's SVD least squares,
which returns its minimum-norm solution (singular values below max(m, n)·ε·σ_max count as
zero), and among candidates whose residuals agree to rounding the smallest ‖x‖ is returned —
the minimum-norm optimum, i.e. what the data cannot determine stays at 0 (fit.py: no change of
a parameter the tracks do not see). This is exact: the minimum-norm point of the optimal set has
its free part equal to its sub-problem's minimum-norm solution, so it is one of the candidates.
"""
from __future__ import annotations

import itertools

import numpy as np

MAX_UNKNOWNS = 6   # 3⁶ = 729 candidates from 2⁶ = 64 factorisations (~5 ms); diagnose needs 3


def _min_norm_operator(A: np.ndarray) -> np.ndarray:
    """P (n, m) with P·y the minimum-norm minimiser of ‖A·x − y‖ for any y: the pseudo-inverse from
    the SVD, singular values below max(m, n)·ε·σ_max treated as zero (numpy lstsq's default)."""
    u, s, vt = np.linalg.svd(A, full_matrices=False)
    keep = s > max(A.shape) * np.finfo(np.float64).eps * (s[0] if s.size else 0.0)
    return (vt[keep].T / s[keep]) @ u[:, keep].T


def _check(A: np.ndarray, b: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> None:
    if A.ndim != 2 or b.ndim != 1 or A.shape[0] != b.shape[0]:
        raise ValueError(f"bounded_lstsq needs A (m, n) and b (m,), got {A.shape} and {b.shape}")
    if A.shape[1] > MAX_UNKNOWNS:
        raise ValueError(f"bounded_lstsq tries all 3**n active sets and supports n <= {MAX_UNKNOWNS} "
                         f"unknowns, got n = {A.shape[1]}")
    if not (np.isfinite(A).all() and np.isfinite(b).all()):
        raise ValueError("bounded_lstsq needs finite A and b")
    if np.isnan(lb).any() or np.isnan(ub).any() or np.any(lb > ub):
        raise ValueError("each lower bound must be a number no greater than its upper bound")


def bounded_lstsq(A: np.ndarray, b: np.ndarray, lb: np.ndarray | float, ub: np.ndarray | float) -> np.ndarray:
    """x (n,) minimising ‖A·x − b‖² subject to lb ≤ x ≤ ub, for dense A (m, n) with n ≤ MAX_UNKNOWNS.

    Bounds broadcast to (n,) and may be infinite; lb == ub fixes a variable. For a rank-deficient A
    the minimum-norm optimum is returned (module docstring)."""
    A = np.asarray(A, np.float64)
    b = np.asarray(b, np.float64)
    if b.ndim == 0:
        b = b.reshape(1)
    n = A.shape[1] if A.ndim == 2 else 0
    lb = np.broadcast_to(np.asarray(lb, np.float64), (n,)).copy()
    ub = np.broadcast_to(np.asarray(ub, np.float64), (n,)).copy()
    _check(A, b, lb, ub)
    if n == 0:
        return np.zeros(0)

    unbounded = _min_norm_operator(A) @ b
    if np.all((unbounded >= lb) & (unbounded <= ub)):   # nothing presses on a bound
        return unbounded

    # every other guess, grouped by its set of free variables: one factorisation per free set,
    # applied to all 2^(pinned) ways of putting the pinned variables on their (finite) bounds
    costs: list[np.ndarray] = []
    points: list[np.ndarray] = []
    for free in itertools.product((True, False), repeat=n):
        free = np.array(free)
        if free.all():
            continue
        pinned = np.flatnonzero(~free)
        choices = [[v for v in (lb[i], ub[i]) if np.isfinite(v)] for i in pinned]
        if not all(choices):
            continue                       # a variable with no finite bound cannot rest on one
        x = np.zeros((int(np.prod([len(c) for c in choices])), n))
        x[:, pinned] = np.array(list(itertools.product(*choices)))
        if free.any():
            rhs = b[None, :] - x[:, pinned] @ A[:, pinned].T
            x[:, free] = rhs @ _min_norm_operator(A[:, free]).T
            ok = np.all((x[:, free] >= lb[free]) & (x[:, free] <= ub[free]), axis=1)
            x = x[ok]
        r = x @ A.T - b[None, :]
        costs.append(np.einsum("ij,ij->i", r, r))
        points.append(x)
    return _pick(np.concatenate(costs), np.concatenate(points), A, b)


def _pick(costs: np.ndarray, points: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The lowest-cost candidate row of `points`; among those equal to it to rounding, the smallest ‖x‖.

    Rounding: a residual r = A·x − b is evaluated to about δ = c·ε·(‖A‖·‖x‖ + ‖b‖), so its squared
    norm to about 2‖r‖δ + δ²; costs closer than that are the same optimum reached through
    different sub-problems (only a rank-deficient A has such ties)."""
    # never empty: the minimum-norm optimum is always a candidate (module docstring)
    best = float(costs.min())
    norms = np.linalg.norm(points, axis=1)
    eps = np.finfo(np.float64).eps
    delta = 16.0 * np.sqrt(A.size + 1.0) * eps * (float(np.linalg.norm(A)) * norms + float(np.linalg.norm(b)))
    tied = costs <= best + 2.0 * np.sqrt(best) * delta + delta * delta
    return points[np.flatnonzero(tied)[np.argmin(norms[tied])]].copy()
