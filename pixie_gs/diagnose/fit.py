"""Fit each candidate effect's parameters to the measured tracks — derivative-free, few runs.

Why derivative-free: the MPM's ground contact (a velocity projection), Coulomb friction and
plastic return mapping are non-smooth, and gradients through thousands of substeps of an
explicit solver are noisy or explode; a parameter's effect on whole trajectories is, in
contrast, smooth enough to fit from a handful of finite-difference runs.
Why so few runs: one simulation costs seconds on a 2-core CPU, so every candidate gets
  1. SCREEN: one probe run per parameter (shared by every diagnosis of the same model);
     with the baseline it gives a finite-difference sensitivity J (the change of every tracked
     coordinate per unit parameter, in the coordinate where the effect is near-linear: the rate
     itself for damping/drag/wind/friction, log10 of a scale factor for E and ρ), and the
     bounded linear least-squares step δ = argmin ‖r − Jδ‖ (lsq.bounded_lstsq) predicts the
     best value and the residual it would leave. Strongly non-linear effects (a part's E or ρ
     scale, whose SSE valley is narrow once oscillation phases shift; plastic yield, a threshold
     with no vanishing value) also get a few more probes — a coarse scan.
  2. VERIFY: the most promising candidates are simulated at their predicted values.
  3. REFINE (top few only): 1 parameter — safeguarded successive-parabolic search (Brent-like,
     bracketing + golden-section fall-back) in log or linear space, seeded with every run
     already made; several parameters (wind) — chord Gauss–Newton with the screening J and
     back-tracking. Each candidate is capped at `max_evals` runs in total.
Every score uses simulated (never predicted) residuals.
Batching: each stage asks for all its runs at once — every candidate's screening probes, every
verification, one step of each refined candidate (the searches run in lock-step, each one's
sequence of points unchanged) — through `Problem.evaluate_many`, which the forward model
simulates as one batched launch on a GPU (forward.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Generator

import numpy as np

from ..errors import ComputationError
from ..lsq import bounded_lstsq
from ..progress import progress
from .effects import Effect, EffectContext, Param
from .locate import residuals, sum_squares

GOLDEN = 0.381966011250105
GROW = 1.618034  # bracket expansion factor: steps grow geometrically while the best point is at an edge


def linear_coord(p: Param, value: float) -> float:
    """Coordinate in which the effect of `p` is near-linear around its vanishing value."""
    if p.log and p.off is not None and p.off > 0:
        return math.log10(value)
    return float(value)


def from_linear_coord(p: Param, u: float) -> float:
    if p.log and p.off is not None and p.off > 0:
        return 10.0 ** u
    return float(u)


@dataclass
class Evaluation:
    """One simulated parameter setting of a candidate."""

    values: dict[str, float]
    sse: float
    pred: np.ndarray | None = None  # (T,M,3) tracked points, kept for the probes and the best


@dataclass
class Candidate:
    """One (effect, part) pair being fitted."""

    effect: Effect
    part: int | None
    params: tuple[Param, ...]
    evaluations: list[Evaluation] = field(default_factory=list)
    jacobian: np.ndarray | None = None       # (n_obs, k) in linear coordinates
    linear_values: dict[str, float] | None = None
    predicted_sse: float | None = None
    base_sse: float | None = None            # SSE of the model the candidate was added to

    @property
    def label(self) -> str:
        return self.effect.name if self.part is None else f"{self.effect.name}[part {self.part}]"

    @property
    def best(self) -> Evaluation | None:
        ok = [e for e in self.evaluations if np.isfinite(e.sse)]
        return min(ok, key=lambda e: e.sse) if ok else None

    @property
    def runs(self) -> int:
        return len(self.evaluations)

    def off_values(self) -> dict[str, float]:
        return {p.name: (p.off if p.off is not None else p.probe) for p in self.params}


class Problem:
    """The fitting target: a current model (scene, cloud), the measured tracks, and a forward model."""

    def __init__(self, model, scene, cloud, measured_x: np.ndarray, visible: np.ndarray,
                 base_pred: np.ndarray, on_run: Callable[[str], None] | None = None) -> None:
        self.model = model
        self.scene = scene
        self.cloud = cloud
        self.measured_x = measured_x
        self.visible = visible
        self.base_pred = base_pred
        self.r0 = residuals(measured_x, base_pred, visible)
        self.base_sse = sum_squares(self.r0)
        self.on_run = on_run

    def flat(self, r: np.ndarray) -> np.ndarray:
        """Visible residual coordinates as one vector."""
        return r[self.visible].reshape(-1)

    def evaluate(self, cand: Candidate, values: dict[str, float], keep_pred: bool = True) -> Evaluation:
        return self.evaluate_many([(cand, values)], keep_pred)[0]

    def evaluate_many(self, requests: list[tuple[Candidate, dict[str, float]]],
                      keep_pred: bool = True, desc: str | None = None) -> list[Evaluation]:
        """Simulate every (candidate, values) request (one batch when the model batches) and
        append each Evaluation to its candidate, in request order; `desc`: progress bar title
        when the runs go one after the other."""
        variants = []
        for cand, values in requests:
            variants.append(cand.effect.apply(self.scene, self.cloud, cand.part, values))
            cand.base_sse = self.base_sse
            if self.on_run is not None:
                self.on_run(cand.label)
        if getattr(self.model, "batch", False):
            preds = self.model.predict_many(variants)
        else:
            preds = [self._predict_one(scene, cloud) for scene, cloud in
                     (progress(variants, desc=desc, total=len(variants), unit="run") if desc else variants)]
        out = []
        for (cand, values), pred in zip(requests, preds):
            if isinstance(pred, ComputationError):
                ev = Evaluation(dict(values), float("inf"), None)  # diverged: infinitely bad
            else:
                sse = sum_squares(residuals(self.measured_x, pred, self.visible))
                ev = Evaluation(dict(values), sse if np.isfinite(sse) else float("inf"), pred if keep_pred else None)
            cand.evaluations.append(ev)
            out.append(ev)
        return out

    def _predict_one(self, scene, cloud):
        """The model's prediction, or the ComputationError of a run that diverged."""
        try:
            return self.model.predict(scene, cloud)
        except ComputationError as err:
            return err


def make_candidates(effects: list[Effect], scene, cloud, parts: list[int]) -> list[Candidate]:
    """(effect, part) pairs: scene effects once, per-part effects once per part in `parts`."""
    out = []
    for effect in effects:
        for part in (parts if effect.per_part else [None]):
            if effect.per_part and part is None:
                continue
            params = effect.params(EffectContext(scene, cloud, part))
            out.append(Candidate(effect, part, params))
    return out


# ---------------------------------------------------------------------------------- screening
def screen_requests(cand: Candidate) -> list[dict[str, float]]:
    """The screening runs of a candidate: per parameter its probe, then its extra probes (the
    others at their vanishing value); one plain run for an effect without parameters."""
    if not cand.params:
        return [{}]
    base = cand.off_values()
    out = []
    for p in cand.params:
        for value in (p.probe,) + tuple(p.extra_probes):
            values = dict(base)
            values[p.name] = value
            out.append(values)
    return out


def screen_finish(problem: Problem, cand: Candidate, evals: list[Evaluation]) -> None:
    """Sensitivity J and the linear-least-squares prediction from the screening runs `evals`
    (in screen_requests order)."""
    if not cand.params:
        return
    base = cand.off_values()
    flat_base = problem.flat(problem.base_pred)
    columns = []
    i = 0
    for p in cand.params:
        ev = evals[i]
        i += 1 + len(p.extra_probes)
        if p.off is None or ev.pred is None:
            continue
        step = linear_coord(p, p.probe) - linear_coord(p, p.off)
        columns.append((problem.flat(ev.pred) - flat_base) / step)
    if len(columns) == len(cand.params) and all(p.off is not None for p in cand.params):
        cand.jacobian = np.stack(columns, axis=1)
        predict_linear(problem, cand, problem.flat(problem.r0), base)


def screen(problem: Problem, cand: Candidate) -> None:
    """Probe runs → sensitivity J and the linear-least-squares predicted values and residual."""
    screen_all(problem, [cand])


def screen_all(problem: Problem, cands: list[Candidate],
               extra: list[tuple[Candidate, dict[str, float]]] = (), desc: str | None = None) -> None:
    """screen() every candidate, their probe runs (and the `extra` runs) asked for at once."""
    requests = [(c, values) for c in cands for values in screen_requests(c)]
    evals = problem.evaluate_many(requests + list(extra), desc=desc)
    i = 0
    for c in cands:
        k = len(screen_requests(c))
        screen_finish(problem, c, evals[i:i + k])
        i += k


def predict_linear(problem: Problem, cand: Candidate, r_flat: np.ndarray, start: dict[str, float]) -> None:
    """Bounded linear least squares of residual `r_flat` on J from `start` → predicted values/SSE."""
    assert cand.jacobian is not None
    J = cand.jacobian
    lo = np.array([linear_coord(p, p.lo) - linear_coord(p, start[p.name]) for p in cand.params])
    hi = np.array([linear_coord(p, p.hi) - linear_coord(p, start[p.name]) for p in cand.params])
    lo = np.minimum(lo, 0.0)
    hi = np.maximum(hi, 0.0)
    if not np.isfinite(J).all() or not np.any(J):
        cand.linear_values, cand.predicted_sse = None, None
        return
    # the same minimiser on the k×k triangle: J = QR gives ‖r − Jδ‖² = ‖r − QQᵀr‖² + ‖Qᵀr − Rδ‖²
    # (J has one row per tracked coordinate — 10⁵ or more — and k ≤ 3 columns)
    Q, R = np.linalg.qr(J)
    delta = bounded_lstsq(R, Q.T @ r_flat, lo, hi + 1e-12)   # exact: every active set of the k ≤ 3 bounds tried
    cand.linear_values = {p.name: from_linear_coord(p, linear_coord(p, start[p.name]) + d)
                          for p, d in zip(cand.params, delta)}
    cand.predicted_sse = float(np.sum(np.square(r_flat - J @ delta)))


def verify_request(cand: Candidate) -> dict[str, float] | None:
    """The linear prediction to simulate, None when there is none or it was run already."""
    if cand.linear_values is None:
        return None
    for ev in cand.evaluations:
        if all(abs(ev.values[k] - v) <= 1e-9 * max(1.0, abs(v)) for k, v in cand.linear_values.items()):
            return None
    return cand.linear_values


def verify(problem: Problem, cand: Candidate) -> None:
    """Simulate the linear prediction (when it is not a run already made)."""
    verify_all(problem, [cand])


def verify_all(problem: Problem, cands: list[Candidate], desc: str | None = None) -> None:
    """verify() every candidate, the runs asked for at once."""
    requests = [(c, v) for c in cands for v in [verify_request(c)] if v is not None]
    if requests:
        problem.evaluate_many(requests, desc=desc)


# ---------------------------------------------------------------------------------- refinement
Search = Generator[dict, Evaluation, None]  # yields parameter values, is sent their Evaluation


def refine(problem: Problem, cand: Candidate, max_evals: int) -> None:
    """Improve the candidate's best fit until it has used `max_evals` runs in total."""
    refine_all(problem, [cand], max_evals)


def refine_search(problem: Problem, cand: Candidate, max_evals: int) -> Search:
    """The refinement of one candidate as a generator of runs (see refine_all)."""
    budget = max_evals - cand.runs
    if budget <= 0 or not cand.params:
        return
    if len(cand.params) == 1:
        yield from _refine_scalar(problem, cand, budget)
    elif cand.jacobian is not None:
        yield from _refine_gauss_newton(problem, cand, budget)


def refine_all(problem: Problem, cands: list[Candidate], max_evals: int, desc: str | None = None) -> None:
    """refine() the candidates in lock-step: each step simulates the next point of every search
    still going, at once. Each search sees only its own runs, so it makes the same choices as
    when run alone. `desc`: title of a progress bar over the steps."""
    searches: list[tuple[Candidate, Search, dict]] = []
    for cand in cands:
        search = refine_search(problem, cand, max_evals)
        values = next(search, None)
        if values is not None:
            searches.append((cand, search, values))

    def steps():
        while searches:
            yield

    for _ in (progress(steps(), desc=desc, unit="step") if desc else steps()):
        evals = problem.evaluate_many([(c, v) for c, _, v in searches])
        going = []
        for (cand, search, _), ev in zip(searches, evals):
            try:
                going.append((cand, search, search.send(ev)))
            except StopIteration:
                pass
        searches[:] = going


def _refine_scalar(problem: Problem, cand: Candidate, budget: int) -> Search:
    p = cand.params[0]
    a, b = p.search_bounds
    tol = 0.02 if p.log else 0.01 * (p.hi - p.lo)
    pts: dict[float, float] = {}
    for ev in cand.evaluations:
        pts[round(p.to_search(ev.values[p.name]), 9)] = ev.sse
    if p.off is not None and (p.lo <= p.off <= p.hi) and not (p.log and p.off <= 0):
        pts.setdefault(round(p.to_search(p.off), 9), problem.base_sse)

    for _ in range(budget):
        u_new = _next_point(pts, a, b, tol)
        if u_new is None:
            return
        ev = yield {p.name: p.from_search(u_new)}
        pts[round(u_new, 9)] = ev.sse


def _next_point(pts: dict[float, float], a: float, b: float, tol: float) -> float | None:
    """Next abscissa of a safeguarded parabolic search on [a, b] given evaluated `pts`."""
    us = sorted(pts)
    fs = [pts[u] if np.isfinite(pts[u]) else 1e300 for u in us]
    if not us:
        return 0.5 * (a + b)
    i = int(np.argmin(fs))
    if len(us) == 1:
        u = us[0]
        return b if (b - u) > (u - a) else a
    if i == 0:
        if us[0] - a > tol:  # expand towards the lower bound
            return max(a, us[0] - max(3.0 * tol, GROW * (us[1] - us[0])))
        if us[1] - us[0] < 2 * tol:
            return None
        return us[0] + GOLDEN * (us[1] - us[0])
    if i == len(us) - 1:
        if b - us[-1] > tol:
            return min(b, us[-1] + max(3.0 * tol, GROW * (us[-1] - us[-2])))
        if us[-1] - us[-2] < 2 * tol:
            return None
        return us[-1] - GOLDEN * (us[-1] - us[-2])
    u0, u1, u2 = us[i - 1], us[i], us[i + 1]
    f0, f1, f2 = fs[i - 1], fs[i], fs[i + 1]
    if u2 - u0 < 2 * tol:
        return None
    num = (u1 - u0) ** 2 * (f1 - f2) - (u1 - u2) ** 2 * (f1 - f0)
    den = (u1 - u0) * (f1 - f2) - (u1 - u2) * (f1 - f0)
    cand = u1 - 0.5 * num / den if den != 0 else None
    if cand is not None and den > 0 and abs(cand - u1) < tol:
        return None  # the parabola's minimum is the best point already: converged
    if cand is None or not (u0 + 0.5 * tol < cand < u2 - 0.5 * tol) or min(abs(cand - u) for u in us) < 0.5 * tol:
        # golden-section step into the larger side of the bracket
        cand = u1 + GOLDEN * (u2 - u1) if (u2 - u1) > (u1 - u0) else u1 - GOLDEN * (u1 - u0)
        if min(abs(cand - u) for u in us) < 0.5 * tol:
            return None
    return cand


def _refine_gauss_newton(problem: Problem, cand: Candidate, budget: int) -> Search:
    """Chord Gauss–Newton with the screening J, halving the step when a run gets worse."""
    for _ in range(budget):
        best = cand.best
        if best is None or best.pred is None:
            return
        r = problem.flat(residuals(problem.measured_x, best.pred, problem.visible))
        predict_linear(problem, cand, r, best.values)
        if cand.linear_values is None:
            return
        target = cand.linear_values
        step = 1.0
        ev = None
        while budget > 0 and step >= 0.25:
            trial = {p.name: from_linear_coord(p, linear_coord(p, best.values[p.name]) + step * (
                linear_coord(p, target[p.name]) - linear_coord(p, best.values[p.name]))) for p in cand.params}
            if max(abs(linear_coord(p, trial[p.name]) - linear_coord(p, best.values[p.name]))
                   for p in cand.params) < 1e-3:
                return
            ev = yield trial
            budget -= 1
            if ev.sse < best.sse:
                break
            step *= 0.5
        if ev is None or ev.sse >= best.sse or budget <= 0:
            return


def drop_predictions(cand: Candidate) -> None:
    """Free memory: keep only the best run's predicted tracks."""
    best = cand.best
    for ev in cand.evaluations:
        if ev is not best:
            ev.pred = None
