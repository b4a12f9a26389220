"""Which way is up, from a capture's shape and from how well each part of it was seen.

Two questions, answered separately:

* the **axis** (up up to sign). Captures and objects are either *flat* (a table top, a floor with
  things on it, a donut: the thinnest principal direction is vertical) or *tall* (a guitar on a
  stand, a bottle, a tree: the longest principal direction is vertical). A single plane holding a
  large share of the opaque Gaussians near the thin axis (a table top, a floor) refines it.
* the **sign**. Cameras are above the horizon in nearly every capture (people hold phones at eye
  height; synthetic captures orbit the upper hemisphere), so upper surfaces are seen by more views
  from closer and end up with finer Gaussians, while the underside is coarse or missing. The
  median Gaussian size in the lowest quarter versus the highest quarter along the axis gives the
  sign when the difference is clear. Without that evidence (meshes converted with one Gaussian
  size, generated objects) the sign comes from support: the flat base an object stands on
  (gravity.score_direction), and for tall objects the low centre of mass (the wide, heavy end down).

All statistics run on a fixed-size opacity-weighted sample, so the cost does not grow with N.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gravity import flat_normals, ransac_planes, score_direction

TALL = 2.0  # longest robust span ≥ this × the middle one: a tall object, up along its long axis
FLAT = 0.8  # thinnest span ≤ this × the middle one: a flat capture, up along its thin axis
PLANE_SHARE = 0.3  # a plane holding this share of the opaque Gaussians defines horizontal
PLANE_NEAR_DEG = 25.0  # … when its normal is within this angle of the thin axis
PLANE_EXTREME = 0.15  # a dominant plane this near one end of the content is a floor: the content is above it
SHARP_CLEAR = 0.15
BASE_CLEAR = 0.02  # flat-base support score (gravity.score_direction) that counts as a base  # nats: the size difference (bottom − top quarter) that decides the sign
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


def _mass_sign(points: np.ndarray, weights: np.ndarray, u: np.ndarray) -> float:
    """> 0 when the centre of mass lies below the middle of the extent along u (heavy end down)."""
    h = points @ u
    lo, hi = np.percentile(h, [2, 98])
    return float(0.5 * (lo + hi) - np.average(h, weights=weights)) / max(hi - lo, 1e-12)


def _wide_end_sign(points: np.ndarray, u: np.ndarray) -> float:
    """> 0 when the lowest 15 % along u is wider (median distance from the axis) than the highest
    15 %: the wide end down, as a bottle or a guitar on its stand stands."""
    c = points - points.mean(axis=0)
    h = c @ u
    lo, hi = np.percentile(h, [2, 98])
    radial = np.linalg.norm(c - np.outer(h, u), axis=1)
    low, high = h < lo + 0.15 * (hi - lo), h > hi - 0.15 * (hi - lo)
    if low.sum() < 10 or high.sum() < 10:
        return 0.0
    a, b = float(np.median(radial[low])), float(np.median(radial[high]))
    return (a - b) / max(a, b, 1e-12)


def estimate_orientation(points: np.ndarray, alphas: np.ndarray, rotations: np.ndarray, log_scales: np.ndarray,
                         spacing: float, seed: int = 0) -> Orientation:
    """Up of a cloud (floaters removed): points (N,3), alphas (N,), rotations (N,4) w,x,y,z,
    log_scales (N,3), spacing (file units). See the module docstring."""
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
    vecs, spans = _robust_axes(p[opaque], w[opaque])
    size = float(np.linalg.norm(np.percentile(p, 99, axis=0) - np.percentile(p, 1, axis=0))) or 1.0
    tol = max(1.5 * spacing, 0.01 * size)
    plane_pos = None
    if spans[2] >= TALL * spans[1]:
        u, kind = vecs[:, 2], "long axis"
    else:
        u, kind = vecs[:, 0], "thin axis"
        planes = ransac_planes(p[opaque], tol, rng, planes=3, hypotheses=300)
        best_share, plane_pos = 0.0, None
        for nrm in planes:
            if abs(float(nrm @ u)) < np.cos(np.radians(PLANE_NEAR_DEG)):
                continue
            d = p[opaque] @ nrm
            hist, edges = np.histogram(d, bins=max(1, int(np.ptp(d) / tol) + 1))
            k = int(np.argmax(hist))
            share = float(np.mean(np.abs(d - 0.5 * (edges[k] + edges[k + 1])) < tol))
            if share >= PLANE_SHARE and share > best_share:
                best_share, u, kind = share, nrm, "dominant plane"
                lo_d, hi_d = np.percentile(d, [2, 98])
                plane_pos = (0.5 * (edges[k] + edges[k + 1]) - lo_d) / max(hi_d - lo_d, 1e-12)
    u = u / np.linalg.norm(u)
    flat_axis_conf = 1.0 - (spans[0] / spans[1] if kind != "long axis" else spans[1] / spans[2])
    sharp = sharpness_sign(p, ls, u)
    if abs(sharp) >= SHARP_CLEAR:
        sign, how = np.sign(sharp), "finer Gaussians on top (seen from above)"
        sign_conf = min(1.0, abs(sharp) / (2 * SHARP_CLEAR))
    elif plane_pos is not None and min(plane_pos, 1.0 - plane_pos) < PLANE_EXTREME:
        sign, how, sign_conf = (1.0 if plane_pos < 0.5 else -1.0), "content on one side of the plane", 1.0
    else:  # no capture evidence: the best flat base among the principal directions, else the heavy end
        normals, flatness = flat_normals(rotations[pick], log_scales[pick])
        axes = (u,) if kind == "long axis" else (u, vecs[:, 0], vecs[:, 1], vecs[:, 2])  # tall: keep its axis
        cands = [sg * v for v in axes for sg in (1.0, -1.0)]
        scored = [score_direction(p, w, normals, flatness, c, tol) for c in cands]
        best = max(scored, key=lambda r: r.score)
        mass = _wide_end_sign(p, u)
        tall_by_mass = kind == "long axis" and abs(mass) > 0.1
        if best.score >= BASE_CLEAR and not (tall_by_mass and min(r.score for r in scored) > 0.5 * best.score):
            rival = max((r.score for r in scored if float(r.up @ best.up) < np.cos(np.radians(20.0))), default=0.0)
            u, kind = best.up / np.linalg.norm(best.up), ("long axis" if kind == "long axis" else "flat base")
            sign, how, sign_conf = 1.0, "the side it stands on", 1.0 - rival / best.score
            flat_axis_conf = 0.5
        elif tall_by_mass:
            sign, how, sign_conf = np.sign(mass), "wide end down", min(1.0, abs(mass) / 0.3)
        else:
            sign, how, sign_conf = 1.0, "no sign evidence", 0.0
    up = float(sign) * u
    confidence = float(np.clip(min(max(flat_axis_conf, 0.0) * 2, 1.0) * sign_conf, 0.0, 1.0))
    return Orientation(up, confidence, f"{kind}, {how}")
