"""Score fitted candidate effects: Gaussian log-likelihood → BIC/AIC, ranking and significance.

The residuals of n observed coordinates are modelled as independent Gaussian with unknown σ;
its maximum-likelihood value σ̂² = SSE/n gives  −2 ln L = n ln(2π σ̂²) + n, so
  BIC = n ln(SSE/n) + k ln n        AIC = n ln(SSE/n) + 2k      (constants dropped)
with k = the number of fitted parameters of the candidate (0 for the baseline).
ΔBIC = BIC_baseline − BIC_candidate > 10 is "very strong" evidence (Kass & Raftery 1995).

Residuals of a real tracker are correlated in time, and any fitted model absorbs some of a
model's systematic error, so a large n makes tiny improvements look "significant". A candidate
is therefore only called significant when it also explains a real share of the *excess* gap —
the part of the squared gap above the tracking-noise floor n·σ²_noise, with σ_noise estimated
from the residual's second time differences (locate.noise_sigma).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

BIC_THRESHOLD = 10.0          # ΔBIC for "very strong" evidence
MIN_EXCESS_EXPLAINED = 0.3    # share of the above-noise squared gap a real effect must explain
MIN_ORIGINAL_SHARE = 0.05     # in a chain: share of the first model's above-noise gap


def bic(sse: float, n: int, k: int) -> float:
    """Bayesian information criterion of a Gaussian residual model (lower is better)."""
    return float(n * np.log(max(sse, 1e-300) / n) + k * np.log(n))


def aic(sse: float, n: int, k: int) -> float:
    """Akaike information criterion of a Gaussian residual model (lower is better)."""
    return float(n * np.log(max(sse, 1e-300) / n) + 2 * k)


def log_likelihood(sse: float, n: int) -> float:
    """Maximised Gaussian log-likelihood ln L(σ̂) with σ̂² = SSE/n."""
    s2 = max(sse, 1e-300) / n
    return float(-0.5 * n * (np.log(2 * np.pi * s2) + 1.0))


@dataclass
class Scored:
    """One candidate's fit and score, with the evidence for it."""

    effect: str
    part: int | None
    params: dict
    num_params: int
    sse: float
    rms: float
    bic: float
    aic: float
    delta_bic: float             # BIC_baseline − BIC (positive: better than the baseline)
    explained: float             # 1 − SSE/SSE_baseline: share of the squared gap it removes
    excess_explained: float      # share of the above-noise squared gap it removes
    significant: bool
    evaluations: int = 0
    evidence: dict = field(default_factory=dict)

    @property
    def label(self) -> str:
        return self.effect if self.part is None else f"{self.effect}[part {self.part}]"

    def to_dict(self) -> dict:
        return {"effect": self.effect, "part": self.part, "params": self.params, "score": self.delta_bic,
                "num_params": self.num_params, "rms": self.rms, "bic": self.bic, "aic": self.aic,
                "delta_bic": self.delta_bic, "explained": self.explained,
                "excess_explained": self.excess_explained, "significant": self.significant,
                "evaluations": self.evaluations, "evidence": self.evidence}


def score_candidate(effect: str, part: int | None, params: dict, num_params: int, sse: float,
                    baseline_sse: float, n: int, noise_sigma: float, evaluations: int = 0,
                    bic_threshold: float = BIC_THRESHOLD,
                    min_excess_explained: float = MIN_EXCESS_EXPLAINED,
                    original_sse: float | None = None, floor_sigma: float = 0.0,
                    floor_factor: float = 2.0) -> Scored:
    """Score one fitted candidate against the baseline (current model) residual.

    `floor_sigma` (units, per coordinate) is the solver-error floor (floor.py): it is part of
    the noise model (the above-noise gap is SSE − n(σ² + f²)), and a significant candidate must
    remove more than `floor_factor`·n·f² of squared gap — more than solver error could fake.

    In a chain (round ≥ 2) `original_sse` is the first model's SSE: a further effect must also
    remove `MIN_ORIGINAL_SHARE` of the ORIGINAL above-noise gap, so that it cannot merely mop up
    the small misfit left by the parameters of the effect added before it.
    """
    base_bic = bic(baseline_sse, n, 0)
    cand_bic = bic(sse, n, num_params)
    delta = base_bic - cand_bic
    explained = 1.0 - sse / baseline_sse if baseline_sse > 0 else 0.0
    excess_explained, removes_enough = _gap_rules(baseline_sse - sse, baseline_sse, n, noise_sigma, original_sse,
                                                  floor_sigma, floor_factor, min_excess_explained)
    significant = bool(delta > bic_threshold and removes_enough)
    return Scored(effect, part, params, num_params, sse, float(np.sqrt(3.0 * sse / n)), cand_bic,
                  aic(sse, n, num_params), float(delta), float(explained), float(excess_explained),
                  significant, evaluations)


def can_be_significant(baseline_sse: float, n: int, noise_sigma: float, original_sse: float | None = None,
                       floor_sigma: float = 0.0, floor_factor: float = 2.0,
                       min_excess_explained: float = MIN_EXCESS_EXPLAINED) -> bool:
    """False when NO candidate, however well it fitted (any SSE ≥ 0), could pass score_candidate's
    significance rules against this baseline — a round that cannot name anything needs no runs.

    With SSE ≥ 0 a candidate removes at most `baseline_sse`, so it fails when the baseline is within
    `floor_factor`·n·f² of zero (solver error could fake all of it), when nothing is above the noise
    (excess 0: it explains no share of it), or, in a chain, when the whole baseline is less than
    MIN_ORIGINAL_SHARE of the first model's above-noise gap.
    """
    return _gap_rules(baseline_sse, baseline_sse, n, noise_sigma, original_sse, floor_sigma, floor_factor,
                      min_excess_explained)[1]


def _gap_rules(removed: float, baseline_sse: float, n: int, noise_sigma: float, original_sse: float | None,
               floor_sigma: float, floor_factor: float, min_excess_explained: float) -> tuple[float, bool]:
    """(share of the above-noise squared gap that removing `removed` of `baseline_sse` explains, whether
    that removal passes score_candidate's rules besides ΔBIC): the share reaches `min_excess_explained`,
    the removal exceeds `floor_factor`·n·f², and in a chain it is MIN_ORIGINAL_SHARE of the first
    model's above-noise gap. Each rule grows with `removed`, so removed = baseline_sse is the best case."""
    noise2 = noise_sigma ** 2 + floor_sigma ** 2
    excess = max(baseline_sse - n * noise2, 0.0)
    excess_explained = removed / excess if excess > 0 else 0.0
    passes = excess_explained >= min_excess_explained and removed > floor_factor * n * floor_sigma ** 2
    if original_sse is not None and original_sse > baseline_sse:
        original_excess = max(original_sse - n * noise2, 1e-300)
        passes = passes and removed / original_excess >= MIN_ORIGINAL_SHARE
    return excess_explained, bool(passes)


def rank(candidates: list[Scored]) -> list[Scored]:
    """Best first: by ΔBIC (which already penalises extra parameters)."""
    return sorted(candidates, key=lambda c: -c.delta_bic)
