"""`prepare_cloud`: floaters → up → ground → objects, written as per-Gaussian `role` / `object_id`.

Nothing is removed or moved: the returned cloud is a copy of the input with two properties added
(`role` uint8, `object_id` int32; codes in scene.py and docs/prepare.md) and a PreparedScene
with the decisions."""
from __future__ import annotations

import time

import numpy as np

from ..splat import SplatCloud, sh_dc_to_rgb
from .density import floater_mask, robust_spacing
from .gravity import GROUND_SHARE, GROUND_WIDER, flat_normals, score_direction
from .orient import estimate_orientation
from .objects import Crop, components, fit_box, parse_crop, pick_objects, robust_box
from .scene import (ROLE_BACKGROUND, ROLE_FLOATER, ROLE_GROUND, ROLE_NAMES, ROLE_OBJECT, PreparedObject,
                    PreparedScene)
from .updir import declared_up, nearest_axis, parse_up, rotation_to_z, turn

SNAP_DEG = 6.0  # an estimate this close to a file axis is taken as that axis (capture tools align files with gravity)
SNAP_TALL_DEG = 12.0  # … and for a tall object's long axis (guitars on stands, bottles against a wall lean)
LOW_CONFIDENCE = 0.1  # below this the estimate is not trusted and the file's +z is kept
ESTIMATE_SAMPLE = 40_000  # Gaussians the up estimate looks at
TINY_COMPONENT = 0.002  # share of the Gaussians below which a cluster away from objects is a floater


def _box(lo: np.ndarray, hi: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in lo], [float(v) for v in hi]]


def prepare_cloud(cloud: SplatCloud, up: "str | np.ndarray | None" = "auto", crop: "str | Crop | None" = None,
                  floaters: bool = True, seed: int = 0) -> tuple[SplatCloud, PreparedScene]:
    """(copy of `cloud` with `role` and `object_id`, PreparedScene) — see the module docstring.

    up: "auto", an axis ("-y"), a vector; crop: "box:…", "sphere:…", "point:…" (file units) or a Crop.
    """
    t0 = time.perf_counter()
    crop_obj = parse_crop(crop) if isinstance(crop, str) or crop is None else crop
    given = parse_up(up) if not isinstance(up, np.ndarray) else parse_up(up)
    source = "given"
    if given is None:
        given = declared_up(cloud.comments)
        source = "declared by the file"
    x = cloud.means.astype(np.float64)
    alpha = cloud.opacities.astype(np.float64)
    n = len(x)
    spacing = robust_spacing(x, seed=seed)
    role = np.full(n, ROLE_BACKGROUND, np.uint8)
    if floaters:
        floater, _ = floater_mask(x, alpha, spacing)
    else:
        floater = np.zeros(n, bool)
    keep = ~floater
    if crop_obj is not None and crop_obj.kind != "point":
        keep &= crop_obj.contains(x)
    # ---- up and the support plane
    if given is None:
        pick = np.nonzero(keep)[0]
        if len(pick) > ESTIMATE_SAMPLE:  # the estimate looks at a fixed-size sample: cost independent of N
            pick = np.sort(np.random.default_rng(seed + 1).choice(pick, ESTIMATE_SAMPLE, replace=False))
        est = estimate_orientation(x[pick], alpha[pick], cloud.rotations[pick], cloud.log_scales[pick], spacing,
                                   seed=seed, colours=sh_dc_to_rgb(cloud.sh_dc[pick]))
        u, method, confidence = est.up, est.method, est.confidence
        if confidence < LOW_CONFIDENCE:  # no clear evidence: keep the file's +z (pixie's own convention)
            u, method = np.array([0.0, 0.0, 1.0]), f"default z (evidence weak: {est.method})"
        axis, angle = nearest_axis(u)
        if angle < (SNAP_TALL_DEG if est.method.startswith("long axis") else SNAP_DEG):  # the file's own axis
            u = parse_up(axis)
            method += f", snapped to the file's {axis} axis ({angle:.1f}° away)"
    else:
        u, method, confidence = given, source, 1.0
    sub = np.nonzero(keep)[0]
    if len(sub) > 12000:
        sub = np.random.default_rng(seed).choice(sub, 12000, replace=False)
    normals, flat = flat_normals(cloud.rotations[sub], cloud.log_scales[sub])
    lo, hi = np.percentile(x[sub], [1, 99], axis=0)
    tol = max(1.5 * spacing, 0.006 * float(np.linalg.norm(hi - lo)))
    s = score_direction(x[sub], np.clip(alpha[sub], 0.05, 1), normals, flat, u, tol, refine=False)
    is_ground = s.support >= GROUND_SHARE and s.footprint_ratio > GROUND_WIDER and s.stable
    base = s.base
    if is_ground and given is None:
        method = f"ground-plane ({method})"
    R = rotation_to_z(u)
    xu = turn(x, R)
    # ---- ground
    lo_all, hi_all = np.percentile(xu[sub], [1, 99], axis=0)
    tol = max(1.5 * spacing, 0.006 * float(np.linalg.norm(hi_all - lo_all)))
    ground_height = None
    ground_extent = None
    if is_ground and crop_obj is None or (is_ground and crop_obj is not None and crop_obj.kind == "point"):
        h = xu[:, 2] - base
        size_all = float(np.linalg.norm(hi_all - lo_all)) or 1.0
        band = np.abs(h[sub]) < tol
        if band.any():  # the floor's own thickness: a thin, exact plane (a mesh) keeps what stands on it
            thick = 2.0 * float(np.percentile(np.abs(h[sub][band]), 95))
            tol = float(np.clip(thick, 1e-4 * size_all, tol))
        on_ground = keep & (np.abs(h) < tol)
        below = keep & (h <= -tol)
        role[on_ground] = ROLE_GROUND
        keep &= ~(on_ground | below)
        ground_height = float(base)
        glo, ghi = robust_box(xu[on_ground][:, :2], q=1.0)
        ground_extent = _box(glo, ghi)
    # ---- objects
    object_id = np.full(n, -1, np.int32)
    idx = np.nonzero(keep)[0]
    if len(idx):
        size = float(np.max(hi_all - lo_all)) or 1.0
        cell = max(4.0 * spacing, size / 100.0)
        labels = components(xu[idx], cell)
        if crop_obj is not None and crop_obj.kind == "point":
            near = int(np.argmin(np.linalg.norm(x[idx] - np.asarray(crop_obj.values), axis=1)))
            obj = np.where(labels == labels[near], 0, -1).astype(np.int32)
        elif crop_obj is not None:
            obj = np.zeros(len(idx), np.int32)
        else:
            centre = np.median(xu[idx[:: max(1, len(idx) // 200_000)]], axis=0)
            obj = pick_objects(xu[idx], alpha[idx], labels, centre)
        object_id[idx] = obj
        role[idx[obj >= 0]] = ROLE_OBJECT
        # tiny clusters away from every object: floaters
        counts = np.bincount(labels, minlength=int(labels.max()) + 1)
        tiny = (counts[labels] < TINY_COMPONENT * n) & (obj < 0)
        role[idx[tiny]] = ROLE_FLOATER
    role[floater] = ROLE_FLOATER
    object_id[role != ROLE_OBJECT] = -1
    objects = []
    for k in range(int(object_id.max()) + 1 if (object_id >= 0).any() else 0):
        m = object_id == k
        flo, fhi = fit_box(xu, mask=m)
        objects.append(PreparedObject(k, int(m.sum()), _box(*robust_box(x, m)), _box(*robust_box(xu, m)),
                                      _box(flo, fhi)))
    axis, angle = nearest_axis(u)
    scene = PreparedScene(
        up=[float(v) for v in u], up_source="auto" if given is None else ("file" if source != "given" else "given"), up_method=method,
        up_confidence=round(float(confidence), 3), nearest_axis=axis, angle_from_axis_deg=round(angle, 2),
        ground_height=ground_height, ground_extent_up=ground_extent, objects=objects,
        counts={name: int((role == code).sum()) for code, name in ROLE_NAMES.items()},
        crop=None if crop_obj is None else f"{crop_obj.kind}:{','.join(f'{v:g}' for v in crop_obj.values)}",
        spacing=float(spacing), count=n)
    out = with_roles(cloud, role, object_id)
    scene.seconds = round(time.perf_counter() - t0, 3)
    return out, scene


def with_roles(cloud: SplatCloud, role: np.ndarray, object_id: np.ndarray) -> SplatCloud:
    """A copy of `cloud` with the per-Gaussian `role` (uint8) and `object_id` (int32) of a preparation."""
    out = cloud.copy()
    out.set("role", role, np.uint8)
    out.set("object_id", object_id, np.int32)
    return out
