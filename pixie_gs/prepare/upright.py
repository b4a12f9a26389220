"""Upright orientation of an object from its shape alone: candidate bases scored by a tiny learned model.

Following the literature on upright orientation of man-made objects (Fu et al. 2008: a small set
of candidate bases from the convex hull, each described by a few geometric cues, ranked by a
learned scorer), an object with no capture evidence (one Gaussian size, one opacity: a converted
mesh, a generated object) gets its up from:

1. **candidates**: the inward normals of the largest convex-hull facet groups (the planes it can
   rest on) and ± its principal axes, each refined by a plane fit to the Gaussians of its base
   band (gravity.score_direction), so a flat base gives an exact normal; and the directions from
   spread-out hull vertices to the centre of mass (things that meet the ground in a point);
2. **descriptors** of the object seen with that candidate up, all rotation-invariant: support
   share and stability of the base, hull area of the base and of the top, centre-of-mass height,
   the width profile along the height, height over diameter, alignment with the principal axes,
   lateral symmetry, mass share near the bottom and the top, the mass profile along the height
   (sixths), how many vertical columns reach the base and the top (`column_ends`), the support,
   base area and floor columns relative to the object's best candidate, and (upright_view) the
   mass by height × ring around the axis, how far the colour of the ends is from the object's
   (a distance, not a colour: the generator's palette is not the world's), whether the ends are
   closed and how thin they are (`FEATURES`);
3. a **scorer**: the mean of a few one-hidden-layer perceptrons (numpy) over the standardised
   descriptors; the candidates of one object compete through a softmax. The weights live in
   pixie_gs/data/upright_scorer.json, trained by scripts/train_upright.py on the dataset's TRAIN
   seeds under random rotations (the benchmark evaluates on the TEST seeds).

Confidence is the softmax mass of the candidates within 20° of the winner: an object whose shape
does not say which way is up (a ball) spreads it over many candidates.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from .gravity import flat_normals, score_direction
from .upright_view import VIEW_FEATURES, view_features

WEIGHTS = Path(__file__).resolve().parent.parent / "data" / "upright_scorer.json"
SAMPLE = 4000  # Gaussians the descriptors look at
HULL_SAMPLE = 1500  # of which the convex hull is taken over
FACET_GROUPS = 24  # largest hull facet groups kept as candidates
APEXES = 10  # hull vertices (spread out) whose direction to the centre of mass is a candidate
GROUP_DEG = 8.0  # facet normals this close form one group
SAME_DEG = 4.0  # candidates this close are one
AGREE_DEG = 20.0  # candidates this close to the winner count towards its confidence
FEATURES = ("support", "stable", "below", "log_footprint", "com_height", "height_over_diameter",
            "width_q1", "width_q2", "width_q3", "width_q4", "base_hull_share", "top_hull_share", "top_support",
            "align_thin", "align_mid", "align_long", "lateral_isotropy", "com_offset", "bottom_mass",
            "top_mass", "base_lateral_share", "top_lateral_share",
            "profile_1", "profile_2", "profile_3", "profile_4", "profile_5", "profile_6",
            "floor_columns", "top_columns", "column_bottom", "column_top",
            "support_rel", "base_hull_rel", "floor_columns_rel") + VIEW_FEATURES
PROFILE_BINS = 6  # mass share per sixth of the height (profile_1 = lowest)
COLUMNS = 8  # lateral grid cells per robust diameter for the column features
RELATIVE = (("support_rel", "support"), ("base_hull_rel", "base_hull_share"), ("floor_columns_rel", "floor_columns"))


@dataclass
class Candidate:
    """up: unit vector (3,) after refinement; features: (len(FEATURES),)."""

    up: np.ndarray
    features: np.ndarray


@dataclass
class UprightResult:
    """up: unit vector (3,); confidence in [0, 1] (softmax mass within AGREE_DEG of it); candidates:
    how many competed."""

    up: np.ndarray
    confidence: float
    candidates: int


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def apex_directions(points: np.ndarray, centre: np.ndarray, count: int = APEXES) -> np.ndarray:
    """Unit directions (K,3) from `count` spread-out convex-hull vertices to `centre`: the up of
    things that meet the ground in a point or a narrow root (a bush, a tree without a pot)."""
    from scipy.spatial import ConvexHull

    try:
        verts = points[ConvexHull(points).vertices]
    except Exception:
        return np.zeros((0, 3))
    chosen = [int(np.argmax(np.linalg.norm(verts - centre, axis=1)))]
    dist = np.linalg.norm(verts - verts[chosen[0]], axis=1)
    while len(chosen) < min(count, len(verts)):  # farthest-point sampling
        chosen.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(verts - verts[chosen[-1]], axis=1))
    d = centre - verts[chosen]
    d = d[np.linalg.norm(d, axis=1) > 1e-12]
    return _unit(d) if len(d) else np.zeros((0, 3))


def hull_facet_groups(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(inward unit normals (K,3), area share (K,)) of the convex hull's facets grouped by normal
    (greedy, largest area first, within GROUP_DEG), largest groups first."""
    from scipy.spatial import ConvexHull

    try:
        hull = ConvexHull(points)
    except Exception:  # degenerate (flat or tiny) clouds
        return np.zeros((0, 3)), np.zeros(0)
    normals = -hull.equations[:, :3]
    tri = points[hull.simplices]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = float(area.sum()) or 1.0
    free = np.ones(len(area), bool)
    groups, shares = [], []
    cos_g = np.cos(np.radians(GROUP_DEG))
    for i in np.argsort(-area):
        if not free[i]:
            continue
        member = free & (normals @ normals[i] > cos_g)
        free &= ~member
        groups.append(_unit((normals[member] * area[member, None]).sum(axis=0)))
        shares.append(float(area[member].sum()) / total)
    order = np.argsort(shares)[::-1]
    return np.asarray(groups)[order], np.asarray(shares)[order]


def _hull_share(normals: np.ndarray, shares: np.ndarray, u: np.ndarray) -> float:
    """Hull area share whose inward normal is within GROUP_DEG of u."""
    if len(normals) == 0:
        return 0.0
    return float(shares[normals @ u > np.cos(np.radians(GROUP_DEG))].sum())


def describe(points: np.ndarray, weights: np.ndarray, normals: np.ndarray, flatness: np.ndarray,
             u: np.ndarray, tol: float, axes: np.ndarray, hull: tuple[np.ndarray, np.ndarray],
             diameter: float, refine: bool = True, colours: "np.ndarray | None" = None) -> Candidate:
    """Candidate (refined by its base plane when `refine`) and its descriptors (FEATURES) for up
    `u` of points (M,3) with opacity weights (M,), Gaussian normals and flatness
    (gravity.flat_normals), principal axes (3,3) as columns thin → long, hull facet groups, the
    robust diameter (file units) and colours (M,3) in [0, 1] (None: no colour cues)."""
    s = score_direction(points, weights, normals, flatness, u, tol, refine=refine)
    u = s.up / np.linalg.norm(s.up)
    top = score_direction(points, weights, normals, flatness, -u, tol, refine=False)
    wsum = float(weights.sum())
    h = points @ u
    base = s.base
    height = max(float(np.percentile(h, 99.7)) - base, 1e-12)
    t = np.clip((h - base) / height, 0.0, 1.0)
    centre = np.average(points, axis=0, weights=weights)
    lateral = points - centre - np.outer(h - centre @ u, u)
    radial = np.linalg.norm(lateral, axis=1)
    quarters = np.minimum((t * 4).astype(int), 3)
    widths = np.array([float(np.percentile(radial[quarters == q], 90)) if (quarters == q).sum() >= 5 else 0.0
                       for q in range(4)])
    widths = widths / max(widths.max(), 1e-12)
    cov = (lateral * weights[:, None]).T @ lateral / wsum
    ev = np.sort(np.linalg.eigvalsh(cov))[1:]  # the zero eigenvalue along u dropped
    isotropy = float(np.sqrt(max(ev[0], 0.0) / max(ev[1], 1e-30)))
    band = np.abs(h - base) < tol
    foot_centre = np.average(lateral[band], axis=0, weights=weights[band]) if band.any() else np.zeros(3)
    r_all = float(np.percentile(radial, 90)) or 1.0
    low, high = t < 0.1, t > 0.9
    base_lat = float(np.percentile(radial[low], 90)) / r_all if low.sum() >= 5 else 0.0
    top_lat = float(np.percentile(radial[high], 90)) / r_all if high.sum() >= 5 else 0.0
    profile = np.bincount(np.minimum((t * PROFILE_BINS).astype(int), PROFILE_BINS - 1), weights=weights,
                          minlength=PROFILE_BINS) / wsum
    f = np.array([
        s.support, float(s.stable), float(weights[h < base - tol].sum() / wsum),
        float(np.log(np.clip(s.footprint_ratio, 1e-3, 10.0))),
        float(np.average(t, weights=weights)), height / max(diameter, 1e-12),
        *widths, _hull_share(*hull, u), _hull_share(*hull, -u), top.support,
        *np.abs(axes.T @ u), isotropy, float(np.linalg.norm(foot_centre)) / r_all,
        float(weights[low].sum() / wsum), float(weights[high].sum() / wsum), base_lat, top_lat,
        *profile, *column_ends(lateral, u, t, diameter), *np.zeros(len(RELATIVE)),
        *view_features(h, t, lateral, radial, r_all, weights, colours, u, diameter)])
    return Candidate(u, f)


def column_ends(lateral: np.ndarray, u: np.ndarray, t: np.ndarray, diameter: float) -> tuple[float, ...]:
    """(share of occupied vertical columns reaching the base, share reaching the top, mean lowest
    and mean highest height fraction over the columns) for lateral offsets (M,3) ⟂ u and height
    fractions t (M,) in [0, 1]. Columns are a lateral grid of diameter / COLUMNS cells. Why: a
    thing standing on its base touches the floor with many columns and its top is ragged (a row
    of books, a plant); turned over, the flat end is on top."""
    a = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    cell = max(diameter, 1e-12) / COLUMNS
    ij = np.floor(np.stack([lateral @ a, lateral @ b], axis=1) / cell).astype(np.int64)
    _, col = np.unique(ij[:, 0] * 1_000_003 + ij[:, 1], return_inverse=True)
    col = col.reshape(-1)
    count = np.bincount(col)
    lo, hi = np.ones(len(count)), np.zeros(len(count))
    np.minimum.at(lo, col, t)
    np.maximum.at(hi, col, t)
    used = count >= 3
    if not used.any():
        return 0.0, 0.0, 0.0, 1.0
    lo, hi = lo[used], hi[used]
    return float(np.mean(lo < 0.05)), float(np.mean(hi > 0.95)), float(lo.mean()), float(hi.mean())


def add_relative(cands: "list[Candidate]") -> None:
    """Fill the RELATIVE features: each candidate's value over the largest among the object's
    candidates (is this the object's biggest flat base?), in place."""
    if not cands:
        return
    F = np.stack([c.features for c in cands])
    for rel, base in RELATIVE:
        i, j = FEATURES.index(rel), FEATURES.index(base)
        top = float(F[:, j].max())
        for c in cands:
            c.features[i] = c.features[j] / top if top > 1e-12 else 0.0


def candidates(points: np.ndarray, alphas: np.ndarray, rotations: np.ndarray, log_scales: np.ndarray,
               spacing: float, seed: int = 0, colours: "np.ndarray | None" = None) -> list[Candidate]:
    """Refined, de-duplicated up candidates of a cloud with their descriptors (module docstring);
    colours (N,3) in [0, 1] or None."""
    rng = np.random.default_rng(seed)
    n = len(points)
    pick = rng.choice(n, SAMPLE, replace=False) if n > SAMPLE else np.arange(n)
    p = np.asarray(points[pick], np.float64)
    w = np.clip(np.asarray(alphas[pick], np.float64), 0.05, 1.0)
    rgb = None if colours is None else np.asarray(colours[pick], np.float64)
    normals, flatness = flat_normals(rotations[pick], np.asarray(log_scales[pick], np.float64))
    lo, hi = np.percentile(p, [1, 99], axis=0)
    diameter = float(np.linalg.norm(hi - lo)) or 1.0
    tol = max(1.5 * spacing, 0.006 * diameter)
    c = p - np.average(p, axis=0, weights=w)
    _, vecs = np.linalg.eigh((c * w[:, None]).T @ c / w.sum())  # columns: thin → long
    hp = p if len(p) <= HULL_SAMPLE else p[rng.choice(len(p), HULL_SAMPLE, replace=False)]
    hull = hull_facet_groups(hp)
    raw = [(v, True) for v in hull[0][:FACET_GROUPS]] + \
        [(sg * vecs[:, k], True) for k in range(3) for sg in (1.0, -1.0)] + \
        [(v, False) for v in apex_directions(hp, np.average(p, axis=0, weights=w))]
    out: list[Candidate] = []
    cos_same = np.cos(np.radians(SAME_DEG))
    for u, refine in raw:
        cand = describe(p, w, normals, flatness, np.asarray(u, np.float64) / np.linalg.norm(u), tol, vecs, hull,
                        diameter, refine, rgb)
        if all(float(cand.up @ o.up) < cos_same for o in out):
            out.append(cand)
    add_relative(out)
    return out


@lru_cache(maxsize=1)
def load_scorer(path: str = str(WEIGHTS)) -> dict:
    """The scorer's weights (JSON written by scripts/train_upright.py) as numpy arrays."""
    raw = json.loads(Path(path).read_text())
    if tuple(raw["features"]) != FEATURES:
        raise RuntimeError(f"{path}: trained on features {raw['features']}, this code computes {list(FEATURES)}; "
                           "retrain with scripts/train_upright.py")
    return {k: np.asarray(v, np.float64) for k, v in raw.items() if k in ("mean", "std", "W1", "b1", "w2", "b2")}


def score(features: np.ndarray, scorer: dict) -> np.ndarray:
    """Scores (K,) of candidate descriptors (K, F): the mean over the scorer's members (one, or an
    ensemble stacked along a first axis: W1 (E,F,H), b1 (E,H), w2 (E,H), b2 (E,)) of a tanh hidden
    layer and a linear output."""
    x = (features - scorer["mean"]) / scorer["std"]
    W1 = scorer["W1"].reshape(-1, *scorer["W1"].shape[-2:])
    b1, w2 = scorer["b1"].reshape(len(W1), -1), scorer["w2"].reshape(len(W1), -1)
    hidden = np.tanh(np.einsum("kf,efh->ekh", x, W1) + b1[:, None, :])
    return (np.einsum("ekh,eh->ek", hidden, w2) + np.reshape(scorer["b2"], -1)[:, None]).mean(axis=0)


def estimate_upright(points: np.ndarray, alphas: np.ndarray, rotations: np.ndarray, log_scales: np.ndarray,
                     spacing: float, seed: int = 0, colours: "np.ndarray | None" = None) -> UprightResult:
    """Up of an object from its shape and colours (module docstring): points (N,3), alphas (N,),
    rotations (N,4) w,x,y,z, log_scales (N,3), spacing (file units), colours (N,3) in [0, 1] or None."""
    cands = candidates(points, alphas, rotations, log_scales, spacing, seed, colours)
    s = score(np.stack([c.features for c in cands]), load_scorer())
    prob = np.exp(s - s.max())
    prob /= prob.sum()
    best = int(np.argmax(s))
    ups = np.stack([c.up for c in cands])
    agree = ups @ ups[best] > np.cos(np.radians(AGREE_DEG))
    return UprightResult(ups[best], float(prob[agree].sum()), len(cands))
