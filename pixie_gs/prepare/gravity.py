"""Which way is up: the support plane a capture or an object rests on.

Gravity leaves one trace in a static capture: things rest on something. A floor or table is a
large, dense plane with (almost) everything on one side of it; a free object has a flat or
flattish base, the band of Gaussians within a small tolerance of its lowest plane. So every
candidate direction u (hull-facet normals, RANSAC planes, principal axes and, as a weak prior,
the file's six axes, since capture tools often write axis-aligned files) is scored by

    support(u) = share of Gaussians within `tol` of the lowest plane ⟂ u
    × stability (the centre of mass projects inside the support's footprint)
    × one-sidedness (few Gaussians below the plane)

and the best wins. A plane holding ≥ 8 % of the Gaussians and reaching well beyond what stands on it (twice its
footprint area) is reported as a ground plane; an object's own flat base is not. Confidence compares the winner with the
best candidate more than 20° away from it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .updir import AXES

AXIS_PRIOR = 1.3  # weak preference for the file's own axes (capture tools' conventions)
GROUND_SHARE = 0.08
GROUND_WIDER = 2.0  # a floor's footprint (area) exceeds what stands on it by this factor; a flat base does not
WEAK_SUPPORT = 0.03  # below this share no flat base is convincing: fall back to the shape  # a support plane holding this share of the Gaussians is a floor/table


@dataclass
class UpEstimate:
    """up: unit vector (3,); confidence in [0, 1]; method: "ground-plane", "flat-base",
    "shape" or "given"; base_height: u·x of the support plane (file units); support: share of
    the sampled Gaussians on that plane; is_ground: the plane is a floor/table in the capture."""

    up: np.ndarray
    confidence: float
    method: str
    base_height: float
    support: float
    is_ground: bool


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def hull_directions(points: np.ndarray, max_candidates: int = 80) -> np.ndarray:
    """Inward normals (K,3) of the largest convex-hull facets: the planes an object can rest on."""
    from scipy.spatial import ConvexHull

    try:
        hull = ConvexHull(points)
    except Exception:  # degenerate (flat or tiny) clouds
        return np.zeros((0, 3))
    normals = -hull.equations[:, :3]
    tri = points[hull.simplices]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    order = np.argsort(-area)
    picked: list[np.ndarray] = []
    for i in order:
        n = normals[i]
        if all(np.dot(n, q) < np.cos(np.radians(4.0)) for q in picked):
            picked.append(n)
        if len(picked) >= max_candidates:
            break
    return np.array(picked) if picked else np.zeros((0, 3))


def ransac_planes(points: np.ndarray, tol: float, rng: np.random.Generator, planes: int = 3,
                  hypotheses: int = 200) -> list[np.ndarray]:
    """Normals of the `planes` largest planes (sequential RANSAC, inliers removed after each)."""
    out: list[np.ndarray] = []
    pts = points
    for _ in range(planes):
        if len(pts) < 50:
            break
        tri = pts[rng.integers(0, len(pts), (hypotheses, 3))]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        ok = np.linalg.norm(n, axis=1) > 1e-12
        if not ok.any():
            break
        n = _unit_rows(n[ok])
        d = np.einsum("hi,hi->h", n, tri[ok, 0])
        probe = pts if len(pts) <= 5000 else pts[rng.choice(len(pts), 5000, replace=False)]
        counts = (np.abs(probe @ n.T - d) < tol).sum(axis=0)
        best = int(np.argmax(counts))
        inl = np.abs(pts @ n[best] - d[best]) < tol
        normal = fit_plane_normal(pts[inl]) if inl.sum() >= 3 else n[best]
        out.append(normal if np.dot(normal, n[best]) >= 0 else -normal)
        pts = pts[~inl]
    return out


def fit_plane_normal(points: np.ndarray) -> np.ndarray:
    """Least-squares plane normal (3,) of points (M,3) (smallest principal direction)."""
    c = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(c[: 20000], full_matrices=False)
    return vt[2]


def inside_footprint(foot2d: np.ndarray, p2d: np.ndarray) -> bool:
    """Whether 2D point `p2d` lies inside the convex hull of footprint points (M,2): true when the
    directions from p to the footprint leave no angular gap of 180° or more."""
    d = foot2d - p2d
    d = d[np.hypot(d[:, 0], d[:, 1]) > 0]
    if len(d) < 3:
        return False
    ang = np.sort(np.arctan2(d[:, 1], d[:, 0]))
    gaps = np.diff(np.concatenate([ang, ang[:1] + 2 * np.pi]))
    return bool(gaps.max() < np.pi * 0.98)


def flat_normals(rotations_wxyz: np.ndarray, log_scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(normal (N,3) = axis of each Gaussian's smallest scale, flatness (N,) in [0, 1]: 1 for a
    disc, 0 for a ball). Surface Gaussians on a floor or a flat base lie in it (normal ∥ up)."""
    from ..splat import quat_to_rotmat

    R = quat_to_rotmat(rotations_wxyz)
    k = np.argmin(log_scales, axis=1)
    normal = R[np.arange(len(k)), :, k]
    s = np.sort(log_scales.astype(np.float64), axis=1)
    flatness = 1.0 - np.exp(-np.clip(s[:, 1] - s[:, 0], 0.0, None))  # 1 − ratio of two smallest sizes
    return normal, flatness


def lowest_layer(h: np.ndarray, weights: np.ndarray, tol: float, min_share: float = 0.004) -> float:
    """Height of the lowest dense layer along u: the centre of the lowest `tol`-wide bin holding at
    least `min_share` of the weight (a floor under a few stray Gaussians is found, not the strays)."""
    lo, hi = np.percentile(h, [0.05, 99.95])
    bins = int(min(4000, max(1, np.ceil((hi - lo) / tol))))
    mass, edges = np.histogram(h, bins=bins, range=(lo, max(hi, lo + tol)), weights=weights)
    dense = np.nonzero(mass >= min_share * weights.sum())[0]
    k = int(dense[0]) if len(dense) else 0
    return float(0.5 * (edges[k] + edges[k + 1]))


@dataclass
class _Score:
    up: np.ndarray
    score: float
    support: float
    base: float
    stable: bool
    footprint_ratio: float


def score_direction(points: np.ndarray, weights: np.ndarray, normals: np.ndarray, flatness: np.ndarray,
                    u: np.ndarray, tol: float, refine: bool = True) -> _Score:
    """Support score of up candidate `u` on sampled points (M,3), opacity weights (M,), Gaussian
    normals (M,3) and flatness (M,): the weighted share of the Gaussians lying flat in the lowest
    plane ⟂ u, reduced when the centre of mass overhangs it or Gaussians lie below it."""
    k = max(1, int(0.003 * len(points)))
    h = points @ u
    base = float(np.partition(h, k)[k])
    band = np.abs(h - base) < tol
    if refine and band.sum() >= 10:
        n = fit_plane_normal(points[band])
        n = n if np.dot(n, u) >= 0 else -n
        if np.dot(n, u) > np.cos(np.radians(12.0)):
            u = n / np.linalg.norm(n)
            h = points @ u
            base = float(np.partition(h, k)[k])
            band = np.abs(h - base) < tol
    total = float(weights.sum())
    align = np.abs(normals[band] @ u)
    lying = (1.0 - flatness[band]) * 0.5 + flatness[band] * (align > np.cos(np.radians(25.0)))
    support = float((weights[band] * lying).sum() / total)
    below = float(weights[h < base - tol].sum() / total)
    a = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    centre = np.average(points, axis=0, weights=weights)
    foot = points[band]
    foot2d = np.stack([foot @ a, foot @ b], axis=1)
    stable = inside_footprint(foot2d, np.array([centre @ a, centre @ b]))
    above = ~band
    all2d = np.stack([points[above] @ a, points[above] @ b], axis=1) if above.any() else np.zeros((1, 2))
    span_all = np.percentile(all2d, 98, axis=0) - np.percentile(all2d, 2, axis=0)
    span_foot = foot2d.max(axis=0) - foot2d.min(axis=0) if len(foot2d) else np.zeros(2)
    ratio = float(np.prod(span_foot) / max(np.prod(span_all), 1e-30))
    score = support * (1.0 if stable else 0.25) * max(0.0, 1.0 - below / 0.05) ** 2
    return _Score(u, score, support, base, stable, ratio)


def tall_axis(points: np.ndarray, weights: np.ndarray, elongation: float = 1.5) -> np.ndarray | None:
    """For an elongated object with no flat base (a tree without a pot, a bush, a figure): its
    long principal axis, pointing away from the narrower end (trunks and legs meet the ground,
    crowns and heads spread out). None when the object is not elongated."""
    c = points - np.average(points, axis=0, weights=weights)
    _, sv, vt = np.linalg.svd(c[:20000], full_matrices=False)
    h = c @ vt[0]
    lo, hi = np.percentile(h, [1, 99])
    lateral = c - np.outer(h, vt[0])
    ext2 = np.percentile(np.linalg.norm(lateral, axis=1), 98) * 2
    if (hi - lo) < elongation * ext2:
        return None
    span = hi - lo
    low_end = h < lo + 0.15 * span
    high_end = h > hi - 0.15 * span
    spread = lambda m: float(np.median(np.linalg.norm(lateral[m], axis=1))) if m.any() else 0.0  # noqa: E731
    return vt[0] if spread(low_end) < spread(high_end) else -vt[0]


def estimate_up(points: np.ndarray, alphas: np.ndarray, rotations: np.ndarray, log_scales: np.ndarray,
                spacing: float, seed: int = 0, sample: int = 12_000) -> UpEstimate:
    """Up vector of a cloud (floaters already removed) from its support plane (module docstring).

    points (N,3), alphas (N,), rotations (N,4) w,x,y,z, log_scales (N,3); spacing: robust
    neighbour distance (file units)."""
    rng = np.random.default_rng(seed)
    pts = np.asarray(points, np.float64)
    w = np.asarray(alphas, np.float64)
    if len(pts) > sample:
        pick = rng.choice(len(pts), sample, replace=False)
        pts, w, rotations, log_scales = pts[pick], w[pick], rotations[pick], log_scales[pick]
    normals, flatness = flat_normals(rotations, log_scales)
    w = np.clip(w, 0.05, 1.0)
    lo, hi = np.percentile(pts, [1, 99], axis=0)
    size = float(np.linalg.norm(hi - lo)) or 1.0
    tol = max(1.5 * spacing, 0.006 * size)
    cands: list[np.ndarray] = []
    hull_pts = pts if len(pts) <= 4000 else pts[rng.choice(len(pts), 4000, replace=False)]
    cands += list(hull_directions(hull_pts, 40))
    for n in ransac_planes(pts, tol, rng):
        cands += [n, -n]
    c = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(c[:20000], full_matrices=False)
    for v in vt:
        cands += [v, -v]
    axes = [s * np.asarray(v) for v in AXES.values() for s in (1.0, -1.0)]
    cands += axes
    best: _Score | None = None
    scored: list[_Score] = []
    for u in cands:
        u = np.asarray(u, np.float64)
        u = u / np.linalg.norm(u)
        s = score_direction(pts, w, normals, flatness, u, tol)
        if max(abs(float(np.dot(s.up, ax))) for ax in axes) > np.cos(np.radians(2.0)):
            s.score *= AXIS_PRIOR
        scored.append(s)
        if best is None or s.score > best.score:
            best = s
    assert best is not None
    if best.support < WEAK_SUPPORT:
        tall = tall_axis(pts, w)
        if tall is not None:
            s = score_direction(pts, w, normals, flatness, tall, tol, refine=False)
            return UpEstimate(tall, 0.3, "shape", s.base, s.support, False)
    rival = max((s.score for s in scored if np.dot(s.up, best.up) < np.cos(np.radians(20.0))), default=0.0)
    confidence = 0.0 if best.score <= 0 else float(np.clip(1.0 - rival / best.score, 0.0, 1.0))
    is_ground = best.support >= GROUND_SHARE and best.footprint_ratio > GROUND_WIDER and best.stable
    method = "ground-plane" if is_ground else ("flat-base" if best.support >= 0.01 else "shape")
    return UpEstimate(best.up, confidence, method, best.base, best.support, is_ground)
