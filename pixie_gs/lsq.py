"""Bounded linear least squares for a few unknowns, without importing scipy.optimize.

Why: diagnose's screening solves min ‖b − A·x‖ subject to lo ≤ x ≤ hi for k ≤ 3 parameters on
a k×k triangle (fit.predict_linear), a microsecond problem; importing scipy.optimize for it costs
~0.35 s of CPU (more on a cold file system), on the critical path of a GPU diagnosis. This is
SciPy's `lsq_linear(A, b, bounds, method="bvls")` for dense A — the unbounded `lstsq` solution
when it is feasible, else the Bounded-Variable Least-Squares iteration (Stark & Parker 1995) —
transcribed step for step (same numpy calls in the same order, so the same floating-point
results; tests/test_lsq.py compares it with SciPy's). SciPy is BSD-3-licensed
(scipy/optimize/_lsq/bvls.py, lsq_linear.py; Copyright (c) 2001-2002 Enthought, Inc. and
2003-2024 SciPy Developers).
"""
from __future__ import annotations

import numpy as np
from numpy.linalg import lstsq


def _kkt_optimality(g: np.ndarray, on_bound: np.ndarray) -> float:
    g_kkt = g * on_bound
    free = on_bound == 0
    g_kkt[free] = np.abs(g[free])
    return float(np.max(g_kkt))


def bounded_lstsq(A: np.ndarray, b: np.ndarray, lb: np.ndarray, ub: np.ndarray, tol: float = 1e-10,
                  max_iter: int | None = None) -> np.ndarray:
    """x minimising ‖A·x − b‖² with lb ≤ x ≤ ub (dense A (m,n), lb < ub elementwise) — the `x` of
    scipy.optimize.lsq_linear(A, b, (lb, ub), method="bvls", tol=tol, max_iter=max_iter)."""
    A = np.asarray(A, np.float64)
    b = np.atleast_1d(np.asarray(b, np.float64))
    n = A.shape[1]
    lb = np.broadcast_to(np.asarray(lb, np.float64), (n,)).copy()
    ub = np.broadcast_to(np.asarray(ub, np.float64), (n,)).copy()
    if np.any(lb >= ub):
        raise ValueError("each lower bound must be strictly less than its upper bound")
    x_lsq = lstsq(A, b, rcond=-1)[0]
    if np.all((x_lsq >= lb) & (x_lsq <= ub)):
        return x_lsq
    return _bvls(A, b, x_lsq, lb, ub, tol, max_iter)


def _bvls(A: np.ndarray, b: np.ndarray, x_lsq: np.ndarray, lb: np.ndarray, ub: np.ndarray, tol: float,
          max_iter: int | None) -> np.ndarray:
    """scipy.optimize._lsq.bvls.bvls (verbose and result bookkeeping left out)."""
    n = A.shape[1]
    x = x_lsq.copy()
    on_bound = np.zeros(n)
    mask = x <= lb
    x[mask] = lb[mask]
    on_bound[mask] = -1
    mask = x >= ub
    x[mask] = ub[mask]
    on_bound[mask] = 1
    free_set = on_bound == 0
    active_set = ~free_set
    free_set, = np.nonzero(free_set)
    r = A.dot(x) - b
    cost = 0.5 * np.dot(r, r)
    g = A.T.dot(r)
    iteration = 0
    # initialisation: least squares on the free variables until it is feasible
    while free_set.size > 0:
        iteration += 1
        A_free = A[:, free_set]
        b_free = b - A.dot(x * active_set)
        z = lstsq(A_free, b_free, rcond=None)[0]
        lbv = z < lb[free_set]
        ubv = z > ub[free_set]
        v = lbv | ubv
        if np.any(lbv):
            ind = free_set[lbv]
            x[ind] = lb[ind]
            active_set[ind] = True
            on_bound[ind] = -1
        if np.any(ubv):
            ind = free_set[ubv]
            x[ind] = ub[ind]
            active_set[ind] = True
            on_bound[ind] = 1
        ind = free_set[~v]
        x[ind] = z[~v]
        r = A.dot(x) - b
        cost = 0.5 * np.dot(r, r)
        g = A.T.dot(r)
        if np.any(v):
            free_set = free_set[~v]
        else:
            break
    max_iter = (n if max_iter is None else max_iter) + iteration
    done = False
    optimality = _kkt_optimality(g, on_bound)
    for iteration in range(iteration, max_iter):  # BVLS loop A
        if optimality < tol:
            done = True
        if done:
            break
        move_to_free = np.argmax(g * on_bound)
        on_bound[move_to_free] = 0
        while True:  # BVLS loop B
            free_set = on_bound == 0
            active_set = ~free_set
            free_set, = np.nonzero(free_set)
            x_free = x[free_set]
            lb_free = lb[free_set]
            ub_free = ub[free_set]
            A_free = A[:, free_set]
            b_free = b - A.dot(x * active_set)
            z = lstsq(A_free, b_free, rcond=None)[0]
            lbv, = np.nonzero(z < lb_free)
            ubv, = np.nonzero(z > ub_free)
            v = np.hstack((lbv, ubv))
            if v.size > 0:
                alphas = np.hstack((lb_free[lbv] - x_free[lbv], ub_free[ubv] - x_free[ubv])) / (z[v] - x_free[v])
                i = np.argmin(alphas)
                i_free = v[i]
                alpha = alphas[i]
                x_free *= 1 - alpha
                x_free += alpha * z
                x[free_set] = x_free
                on_bound[free_set[i_free]] = -1 if i < lbv.size else 1
            else:
                x_free = z
                x[free_set] = x_free
                break
        r = A.dot(x) - b
        cost_new = 0.5 * np.dot(r, r)
        if cost - cost_new < tol * cost:
            done = True
        cost = cost_new
        g = A.T.dot(r)
        optimality = _kkt_optimality(g, on_bound)
    return x
