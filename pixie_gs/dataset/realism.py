"""Make a clean generated object look like a trained 3DGS capture (issue 12).

The converter's Gaussians all share one opacity, have degree-0 colour and tidy disc shapes; real
captures (benchmarks/bench_splat_stats.py, docs/real_vs_generated.md) spread opacity from 0.01 to
0.99 (median ≈ 0.3), have log10 anisotropy ≈ 0.4–2.5, twice the colour noise, needles and oversized
Gaussians, view-dependent colour (f_rest), unseen undersides, a few floaters and a small tilt left
by up-estimation. `capture_like` applies all of these, drawing everything from the object's RNG so
that objects stay deterministic per seed. Two more gaps between converted meshes and captures: a
capture holds surfaces only (3DGS optimises what the cameras see; a converted mesh is filled only on
request), so most objects are drawn surface-only (`draw_surface_only`, before the Gaussian budget is
split); and real surfaces carry texture (glaze patterns, labels, sprinkles, grain) rather than one
colour per part, so many objects get procedural bands, blotches or speckles on some parts. Labels follow the Gaussians (floaters copy the labels of
their nearest Gaussian), so every part keeps constant values.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..splat import SplatCloud, quat_to_rotmat, rotmat_to_quat

REALISTIC_OPACITY_SHARE = 0.8  # objects whose opacity follows captures (the rest: one high opacity)
OPACITY_LOGIT_MEAN = (-2.2, 0.0)  # per-object mean of the opacity logit
OPACITY_LOGIT_STD = (1.5, 3.0)
NEEDLE_SHARE = (0.0, 0.08)  # Gaussians stretched ×3–12 along one axis
OVERSIZED_SHARE = (0.0, 0.03)  # Gaussians grown ×2–6, faint
AXIS_NOISE_LN = (0.2, 0.6)  # per-axis log std-dev jitter (natural log)
COLOUR_NOISE = (0.01, 0.15)  # extra per-Gaussian RGB noise std-dev
SH_SHARE = 0.45  # objects with view-dependent colour
SH_DEGREE_P = (0.7, 0.2, 0.1)  # degree 1, 2, 3
SH_ENERGY = (0.02, 0.5)  # per-object median ‖f_rest‖
UNDERSIDE_SHARE = 0.4  # objects whose bottom few per cent are missing (never seen by cameras)
CAP_SHARE = 0.2  # objects with a side cap cut away (partial capture)
FLOATER_SHARE = (0.0, 0.04)
TILT_STD_DEG = 6.0  # residual up error left by preparation, capped at TILT_MAX_DEG
TILT_MAX_DEG = 20.0
MIN_KEEP_PER_PART = 16
SURFACE_ONLY_SHARE = 0.85  # objects without interior Gaussians, like every capture (the rest keep their fill)
TEXTURE_SHARE = 0.6  # objects with procedural texture on some parts
TEXTURE_PART_SHARE = 0.7  # of their parts, the share that is textured
TEXTURE_KINDS = ("bands", "blotches", "speckle")


@dataclass
class RealismRecord:
    """What `capture_like` did to one object (stored in the object's index record)."""

    opacity_mode: str
    sh_degree: int
    sh_energy: float
    dropped: int
    floaters: int
    tilt_deg: float
    textured_parts: int = 0
    leftovers: int = 0

    def to_dict(self) -> dict:
        return {"opacity_mode": self.opacity_mode, "sh_degree": self.sh_degree,
                "sh_energy": round(self.sh_energy, 4), "dropped": self.dropped, "floaters": self.floaters,
                "tilt_deg": round(self.tilt_deg, 3), "textured_parts": self.textured_parts,
                "leftovers": self.leftovers}


def draw_surface_only(rng: np.random.Generator) -> bool:
    """Whether this object is built without interior (fill) Gaussians, as a trained capture is."""
    return bool(rng.random() < SURFACE_ONLY_SHARE)


def _texture_weight(p: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    """Per-Gaussian mix weight in [0, 1] of a second colour over the points `p` (N,3) of one part."""
    lo, hi = p.min(0), p.max(0)
    ext = float(np.linalg.norm(hi - lo)) + 1e-9
    if kind == "bands":  # stripes and glaze bands: a sharpened sinusoid along one direction (often the height)
        d = np.array([0.0, 0.0, 1.0]) if rng.random() < 0.5 else rng.normal(size=3)
        d /= np.linalg.norm(d)
        phase = 2 * math.pi * rng.uniform(2, 15) * (p @ d) / ext + rng.uniform(0, 2 * math.pi)
        return 1.0 / (1.0 + np.exp(-rng.uniform(1, 10) * np.sin(phase)))
    if kind == "blotches":  # painted motifs, stains, grain knots: soft spots around random surface points
        k = int(rng.integers(3, 31))
        centres = p[rng.integers(0, len(p), k)]
        radii = rng.uniform(0.03, 0.2, k) * ext
        w = np.zeros(len(p))
        for c, r in zip(centres, radii):
            w = np.maximum(w, np.exp(-np.sum((p - c) ** 2, axis=1) / r ** 2))
        return w
    return (rng.random(len(p)) < rng.uniform(0.02, 0.2)).astype(np.float64)  # speckle: sprinkles, flecks


def _textured_rgb(rgb: np.ndarray, p: np.ndarray, part_id: np.ndarray, rng: np.random.Generator
                  ) -> tuple[np.ndarray, int]:
    """`rgb` (N,3) with procedural texture on a random share of the parts; and how many parts got one."""
    out = rgb.astype(np.float64).copy()
    textured = 0
    for pid in np.unique(part_id):
        if rng.random() >= TEXTURE_PART_SHARE:
            continue
        sel = np.nonzero(part_id == pid)[0]
        kind = TEXTURE_KINDS[int(rng.integers(len(TEXTURE_KINDS)))]
        w = _texture_weight(p[sel].astype(np.float64), kind, rng) * rng.uniform(0.5, 1.0)
        base = out[sel].mean(0)
        if rng.random() < 0.5:  # a contrasting colour
            second = rng.random(3)
        else:  # a darker or lighter shade of the part's own colour
            second = np.clip(base * rng.choice([rng.uniform(0.25, 0.7), rng.uniform(1.3, 2.0)]), 0.0, 1.0)
        if kind == "speckle" and rng.random() < 0.5:  # multicoloured sprinkles
            palette = rng.random((int(rng.integers(2, 6)), 3))
            second = palette[rng.integers(0, len(palette), len(sel))]
        out[sel] = out[sel] * (1.0 - w[:, None]) + np.asarray(second) * w[:, None]
        textured += 1
    return np.clip(out, 0.0, 1.0), textured


def _keep_mask(cloud: SplatCloud, part_id: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Drop an unseen underside and/or a side cap; never empties a part (then nothing is cut)."""
    p = cloud.means.astype(np.float64)
    lo, hi = p.min(0), p.max(0)
    ext = np.maximum(hi - lo, 1e-9)
    keep = np.ones(len(p), bool)
    if rng.random() < UNDERSIDE_SHARE:
        keep &= p[:, 2] > lo[2] + rng.uniform(0.005, 0.04) * ext[2]
    if rng.random() < CAP_SHARE:
        theta = rng.uniform(0, 2 * math.pi)
        d = np.array([math.cos(theta), math.sin(theta), rng.uniform(-0.3, 0.3)])
        d /= np.linalg.norm(d)
        proj = (p - (lo + hi) / 2) @ d
        keep &= proj < np.quantile(proj, 1.0 - rng.uniform(0.05, 0.2))
    for pid in np.unique(part_id):
        if (keep & (part_id == pid)).sum() < MIN_KEEP_PER_PART:
            return np.ones(len(p), bool)
    return keep


def horizontal_tilt(angle_rad: float, azimuth_rad: float) -> np.ndarray:
    """(3,3) rotation by `angle_rad` about the horizontal axis at `azimuth_rad` from +x (Rodrigues):
    a capture's residual tilt here, the training tilt augmentation in model/batch.py."""
    axis = np.array([math.cos(azimuth_rad), math.sin(azimuth_rad), 0.0])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1 - math.cos(angle_rad)) * k @ k


def _tilt(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    angle = min(abs(rng.normal(0.0, TILT_STD_DEG)), TILT_MAX_DEG)
    phi = rng.uniform(0, 2 * math.pi)
    return horizontal_tilt(math.radians(angle), phi), angle


def capture_like(cloud: SplatCloud, part_id: np.ndarray, rng: np.random.Generator,
                 keep_opacity: np.ndarray | None = None) -> tuple[SplatCloud, np.ndarray, RealismRecord]:
    """A capture-like version of `cloud` (and its per-Gaussian part ids), with what was done.

    keep_opacity: (n,) bool, Gaussians whose opacity stays as given (the interior leftovers of
    `leftovers.py`, opaque in captures); every other step applies to them as to the rest."""
    keep = _keep_mask(cloud, part_id, rng)
    dropped = int((~keep).sum())
    held = np.zeros(len(cloud), bool) if keep_opacity is None else np.asarray(keep_opacity, bool)
    if dropped:
        cloud, part_id, held = cloud.subset(np.nonzero(keep)[0]), part_id[keep], held[keep]
    n = len(cloud)

    # floaters: faint Gaussians scattered in the object's box, labelled like their nearest Gaussian
    n_float = int(round(n * rng.uniform(*FLOATER_SHARE)))
    if n_float:
        lo, hi = cloud.means.min(0), cloud.means.max(0)
        pos = rng.uniform(lo, hi, size=(n_float, 3)).astype(np.float32)
        from scipy.spatial import cKDTree

        _, near = cKDTree(cloud.means).query(pos, k=1)
        extra = cloud.subset(near)
        extra.means = pos
        cloud = SplatCloud.concatenate([cloud, extra])
        part_id = np.concatenate([part_id, part_id[near]])
        held = np.concatenate([held, np.zeros(n_float, bool)])
        n = len(cloud)
    floater = np.zeros(n, bool)
    floater[n - n_float:] = n_float > 0

    # shapes: per-axis jitter, needles, oversized Gaussians
    ls = cloud.log_scales.astype(np.float64)
    ls = ls + rng.normal(0.0, rng.uniform(*AXIS_NOISE_LN), size=ls.shape)
    needle = rng.random(n) < rng.uniform(*NEEDLE_SHARE)
    axis = rng.integers(0, 3, n)
    ls[needle, axis[needle]] += np.log(rng.uniform(3, 12, needle.sum()))
    ls[needle] -= np.log(1.5)
    big = rng.random(n) < rng.uniform(*OVERSIZED_SHARE)
    ls[big] += np.log(rng.uniform(2, 6, big.sum()))[:, None]
    cloud.log_scales = ls.astype(np.float32)

    # opacity: capture-like logit spread (faint oversized Gaussians and floaters)
    if rng.random() < REALISTIC_OPACITY_SHARE:
        mode = "capture"
        logit = rng.normal(rng.uniform(*OPACITY_LOGIT_MEAN), rng.uniform(*OPACITY_LOGIT_STD), n)
    else:
        mode = "constant"
        logit = cloud.opacity_logits.astype(np.float64)
    logit[big | floater] -= rng.uniform(1.0, 3.0, int((big | floater).sum()))
    logit[held] = cloud.opacity_logits[held]
    cloud.opacity_logits = np.clip(logit, -7.0, 7.0).astype(np.float32)

    # texture, then colour noise, on the DC term (RGB = 0.5 + C0·dc)
    from ..splat import rgb_to_sh_dc

    rgb, textured = cloud.rgb(), 0
    if rng.random() < TEXTURE_SHARE:
        rgb, textured = _textured_rgb(rgb, cloud.means, part_id, rng)
    sigma = rng.uniform(*COLOUR_NOISE)
    if sigma > 0 or textured:
        rgb = np.clip(rgb + rng.normal(0.0, sigma, (n, 3)), 0.0, 1.0)
        cloud.sh_dc = rgb_to_sh_dc(rgb.astype(np.float32)).astype(np.float32)

    # view-dependent colour: f_rest of degree 1–3 with a per-object energy
    degree, energy = 0, 0.0
    if rng.random() < SH_SHARE:
        degree = int(rng.choice([1, 2, 3], p=SH_DEGREE_P))
        energy = float(rng.uniform(*SH_ENERGY))
        k = 3 * ((degree + 1) ** 2 - 1)
        rest = rng.normal(0.0, 1.0, (n, k))
        rest *= (energy * rng.lognormal(0.0, 0.5, n) / np.maximum(np.linalg.norm(rest, axis=1), 1e-9))[:, None]
        cloud.sh_rest = rest.astype(np.float32)
        cloud.property_order = [c for c in cloud.property_order if not c.startswith("f_rest_")]
        at = cloud.property_order.index("f_dc_2") + 1
        cloud.property_order[at:at] = [f"f_rest_{i}" for i in range(k)]

    # residual tilt about the base centre
    R, angle = _tilt(rng)
    if angle > 0:
        base = cloud.means.mean(0).astype(np.float64)
        base[2] = float(cloud.means[:, 2].min())
        cloud.means = ((cloud.means - base) @ R.T + base).astype(np.float32)
        cloud.rotations = rotmat_to_quat(R[None] @ quat_to_rotmat(cloud.quats)).astype(np.float32)
        for names in (("nx", "ny", "nz"),):
            if all(cloud.has(c) for c in names):
                nrm = np.stack([cloud.get(c) for c in names], 1) @ R.T
                for j, c in enumerate(names):
                    cloud.set(c, nrm[:, j].astype(np.float32))
    return cloud, part_id, RealismRecord(mode, degree, energy, dropped, n_float, angle, textured,
                                         int(held.sum()))
