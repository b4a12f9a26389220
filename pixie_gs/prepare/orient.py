"""Which way is up, from a capture's shape and from how well each part of it was seen.

Three kinds of evidence, tried in this order:

* **capture evidence** (a trained capture: its opacities spread, `looks_captured`). The *axis* (up
  up to sign): captures are either *flat* (a table top, a floor with things on it, a donut: the
  thinnest principal direction is vertical) or *tall* (a guitar on a stand, a bottle, a tree: the
  longest principal direction is vertical); a single plane holding a large share of the opaque
  Gaussians near the thin axis (a table top, a floor) refines it. The *sign*: cameras are above
  the horizon in nearly every capture (people hold phones at eye height; synthetic captures orbit
  the upper hemisphere), so upper surfaces are seen by more views from closer and end up with
  finer Gaussians, while the underside is coarse or missing. The median Gaussian size in the
  lowest quarter versus the highest quarter along the axis gives the sign when the difference is
  clear.
* a **floor or table** the content stands on (`_floor`: a plane holding many Gaussians, wider than
  what stands on it, nothing below it): up is its normal towards the content.
* the **object's own shape** (converted meshes with one Gaussian size, generated objects, captures
  without a clear size cue): candidate bases from the convex hull and the principal axes, ranked
  by a small learned scorer (upright.py).

All statistics run on a fixed-size opacity-weighted sample, so the cost does not grow with N.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gravity import GROUND_SHARE, GROUND_WIDER, flat_normals, ransac_planes, score_direction
from .upright import estimate_upright

TALL = 2.0  # longest robust span ≥ this × the middle one: a tall object, up along its long axis
PLANE_SHARE = 0.3  # a plane holding this share of the opaque Gaussians defines horizontal
PLANE_NEAR_DEG = 25.0  # … when its normal is within this angle of the thin axis
SHARP_CLEAR = 0.15  # nats: the size difference (bottom − top quarter) that decides the sign
CAPTURE_SPREAD = 0.2  # opacity interquartile range from which a cloud counts as a trained capture
SAMPLE = 20_000


@dataclass
class Orientation:
    """up: unit vector (3,); confidence in [0, 1]; method: how the axis and the sign were found."""

    up: np.ndarray
    confidence: float
    method: str


def _robust_axes(points: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(principal directions (3,3) as columns, robust 3–97 % spans (3,)) sorted thin → long."""
    c = points - np.average(points, axis=0, weights=weights)
    cov = (c * weights[:, None]).T @ c / weights.sum()
    _, vecs = np.linalg.eigh(cov)
    proj = c @ vecs
    spans = np.percentile(proj, 97, axis=0) - np.percentile(proj, 3, axis=0)
    order = np.argsort(spans)
    return vecs[:, order], spans[order]


def sharpness_sign(points: np.ndarray, log_scales: np.ndarray, u: np.ndarray) -> float:
    """How much finer (nats) the Gaussians of the highest quarter along `u` are than those of the
    lowest quarter: the mean of the differences of the median largest log-size and of the median
    mean log-size (bottom − top). > 0 when the `u` end was seen better, so nearer the cameras."""
    h = points @ u
    lo, hi = np.percentile(h, [2, 98])
    q = 0.25 * (hi - lo)
    bottom, top = h < lo + q, h > hi - q
    if bottom.sum() < 20 or top.sum() < 20:
        return 0.0
    diffs = [float(np.median(v[bottom]) - np.median(v[top])) for v in (log_scales.max(axis=1), log_scales.mean(axis=1))]
    return 0.5 * (diffs[0] + diffs[1])


def estimate_orientation(points: np.ndarray, alphas: np.ndarray, rotations: np.ndarray, log_scales: np.ndarray,
                         spacing: float, seed: int = 0, colours: "np.ndarray | None" = None) -> Orientation:
    """Up of a cloud (floaters removed): points (N,3), alphas (N,), rotations (N,4) w,x,y,z,
    log_scales (N,3), spacing (file units), colours (N,3) in [0, 1] or None (used by the object's
    own shape cues only). See the module docstring."""
    rng = np.random.default_rng(seed)
    n = len(points)
    pick = rng.choice(n, SAMPLE, replace=False) if n > SAMPLE else np.arange(n)
    p = np.asarray(points[pick], np.float64)
    a = np.asarray(alphas[pick], np.float64)
    ls = np.asarray(log_scales[pick], np.float64)
    w = np.clip(a, 0.05, 1.0)
    opaque = a > 0.5
    if opaque.sum() < 0.2 * len(p):
        opaque = a >= np.median(a)
    size = float(np.linalg.norm(np.percentile(p, 99, axis=0) - np.percentile(p, 1, axis=0))) or 1.0
    tol = max(1.5 * spacing, 0.01 * size)
    if looks_captured(a):
        found = _capture_evidence(p, w, ls, opaque, tol, rng)
        if found is not None:
            return found
    floor = _floor(p[opaque], w[opaque], rotations[pick][opaque], ls[opaque], tol, rng)
    if floor is not None:
        return Orientation(floor, 1.0, "floor plane, content above it")
    shape = estimate_upright(p, a, rotations[pick], ls, spacing, seed=seed,
                             colours=None if colours is None else colours[pick])
    return Orientation(shape.up, shape.confidence,
                       f"object shape (learned scorer over {shape.candidates} candidate bases)")


def _capture_evidence(p: np.ndarray, w: np.ndarray, ls: np.ndarray, opaque: np.ndarray, tol: float,
                      rng: np.random.Generator) -> "Orientation | None":
    """Axis from the principal spans (tall: long axis; else thin axis, refined by a dominant plane),
    sign from finer Gaussians on top; None when the size difference is not clear."""
    vecs, spans = _robust_axes(p[opaque], w[opaque])
    if spans[2] >= TALL * spans[1]:
        u, kind = vecs[:, 2], "long axis"
    else:
        u, kind = vecs[:, 0], "thin axis"
        planes = ransac_planes(p[opaque], tol, rng, planes=3, hypotheses=300)
        best_share = 0.0
        for nrm in planes:
            if abs(float(nrm @ u)) < np.cos(np.radians(PLANE_NEAR_DEG)):
                continue
            d = p[opaque] @ nrm
            hist, edges = np.histogram(d, bins=max(1, int(np.ptp(d) / tol) + 1))
            k = int(np.argmax(hist))
            share = float(np.mean(np.abs(d - 0.5 * (edges[k] + edges[k + 1])) < tol))
            if share >= PLANE_SHARE and share > best_share:
                best_share, u, kind = share, nrm, "dominant plane"
    u = u / np.linalg.norm(u)
    flat_axis_conf = 1.0 - (spans[0] / spans[1] if kind != "long axis" else spans[1] / spans[2])
    sharp = sharpness_sign(p, ls, u)
    if abs(sharp) < SHARP_CLEAR:
        return None
    sign_conf = min(1.0, abs(sharp) / (2 * SHARP_CLEAR))
    confidence = float(np.clip(min(max(flat_axis_conf, 0.0) * 2, 1.0) * sign_conf, 0.0, 1.0))
    return Orientation(float(np.sign(sharp)) * u, confidence, f"{kind}, finer Gaussians on top (seen from above)")


def looks_captured(alphas: np.ndarray) -> bool:
    """Whether opacities spread as a trained capture's do (interquartile range ≥ CAPTURE_SPREAD);
    converted meshes and generated objects have one opacity, so their Gaussian sizes say nothing
    about where the cameras were."""
    q1, q3 = np.percentile(alphas, [25, 75])
    return bool(q3 - q1 >= CAPTURE_SPREAD)


def _floor(points: np.ndarray, weights: np.ndarray, rotations: np.ndarray, log_scales: np.ndarray, tol: float,
           rng: np.random.Generator) -> "np.ndarray | None":
    """Up of a floor or table the content stands on (a RANSAC plane that gravity.score_direction
    calls ground: ≥ GROUND_SHARE of the Gaussians, wider than what stands on it, nothing below),
    pointing towards the content; None when there is none."""
    normals, flatness = flat_normals(rotations, log_scales)
    best = None
    for nrm in ransac_planes(points, tol, rng, planes=3, hypotheses=300):
        for c in (nrm, -nrm):
            s = score_direction(points, weights, normals, flatness, c, tol)
            if s.support >= GROUND_SHARE and s.footprint_ratio > GROUND_WIDER and s.stable and \
                    (best is None or s.score > best.score):
                best = s
    return None if best is None else best.up / np.linalg.norm(best.up)
