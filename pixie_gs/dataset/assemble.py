"""Build one labelled object: parts → labels → recipe meshes → Gaussians with per-part attributes.

Everything random is drawn from one `numpy.random.Generator` seeded by the object's own seed,
so an object depends on nothing but (class, seed, Gaussian budget): identical bytes whichever
worker builds it.
"""
from __future__ import annotations

import math

import numpy as np

from ..convert import mesh_to_splat
from ..errors import InputError
from ..splat import SplatCloud
from .leftovers import LEFTOVER_OBJECT_SHARE, interior_leftovers, leftover_rng
from .lighting import LIGHTING_OBJECT_SHARE, bake_lighting, lighting_rng
from .labels import ClassSpec, choose_parts, sample_part_values
from .primitives import rotation_z
from .realism import capture_like, draw_surface_only
from . import household  # noqa: F401  (registers the everyday-object recipes)
from .shapes import RECIPES, Piece

SURFACE_SHARE_OF_FILLED = 0.4  # filled pieces: this share of their Gaussians on the surface, rest inside
MIN_GAUSSIANS_PER_PIECE = 16
SCALE_RANGE = (0.8, 1.25)  # object size multiplier
COUNT_RANGE = (0.8, 1.2)  # Gaussian count multiplier around the requested budget
GAUSSIAN_SIZE_RANGE = (0.8, 1.3)  # multiplier of the converter's Gaussian std-devs
OPACITY_RANGE = (0.7, 0.97)  # per-object Gaussian opacity α (real captures vary)


def allocate_counts(pieces: list[Piece], total: int) -> list[tuple[int, int]]:
    """(surface, interior) Gaussian counts per piece: shares ∝ area × weight, each ≥ 16."""
    demand = np.array([float(p.mesh.area) * p.weight for p in pieces])
    demand = demand / demand.sum()
    budget = max(total - MIN_GAUSSIANS_PER_PIECE * len(pieces), 0)
    counts = MIN_GAUSSIANS_PER_PIECE + np.floor(demand * budget).astype(int)
    counts[int(np.argmax(demand))] += max(total - int(counts.sum()), 0)  # rounding remainder
    out = []
    for p, c in zip(pieces, counts):
        if p.fill:
            surface = max(int(round(c * SURFACE_SHARE_OF_FILLED)), 1)
            out.append((surface, int(c) - surface))
        else:
            out.append((int(c), 0))
    return out


def extent_record(cloud: SplatCloud) -> dict:
    """The record fields that describe a cloud's extent: its Gaussian count and its centres' bounds (m,
    rounded to 0.01 mm); shared by objects, pairs and objects on a floor."""
    lo, hi = cloud.bounds()
    return {"gaussians": len(cloud), "bounds_min_m": [round(float(v), 5) for v in lo],
            "bounds_max_m": [round(float(v), 5) for v in hi]}


def build_object(spec: ClassSpec, object_seed: int, n_gaussians: int, realistic: bool = False,
                 leftover_share: float = LEFTOVER_OBJECT_SHARE,
                 lighting_share: float = LIGHTING_OBJECT_SHARE) -> tuple[SplatCloud, dict]:
    """One labelled object of class `spec` from `object_seed`, about `n_gaussians` Gaussians.

    realistic: make it look like a trained capture (pixie_gs/dataset/realism.py: opacity and shape
    spread, view-dependent colour, partial surfaces, floaters, a small tilt). leftover_share: the chance
    (0–1) that a realistic object holds interior leftovers (dataset/leftovers.py); the draw comes from the
    leftovers' own RNG, so objects that draw none are the same for any share. lighting_share: the chance
    that a realistic object's colours carry baked lighting (dataset/lighting.py; its own RNG likewise).

    Returns the cloud (with material_id, E, nu, density, part_id per Gaussian) and its index
    record (class, parts with sampled values and counts, seed, shape parameters).
    """
    if spec.recipe not in RECIPES:
        raise InputError(f"class '{spec.name}' names unknown recipe '{spec.recipe}' "
                         f"(known: {', '.join(sorted(RECIPES))})")
    rng = np.random.default_rng(object_seed)
    present = choose_parts(spec, rng)
    values, draws = sample_part_values(spec, present, rng)
    to_class = {**{p.name: p.name for p in spec.parts}, **spec.part_map}
    to_recipe = {c: r for r, c in to_class.items()}
    pieces, shape = RECIPES[spec.recipe](rng, {to_recipe.get(name, name) for name in present})
    for piece in pieces:
        piece.part = to_class.get(piece.part, piece.part)
        if piece.part not in values:
            raise InputError(f"class '{spec.name}': recipe '{spec.recipe}' made part '{piece.part}', which "
                             f"is not among the object's parts {present} (map it with part_map)")
    missing = [name for name in present if not any(p.part == name for p in pieces)]
    if missing:
        raise InputError(f"class '{spec.name}': recipe '{spec.recipe}' made no geometry for {missing}")

    scale = float(rng.uniform(*SCALE_RANGE))
    yaw = float(rng.uniform(0.0, 2.0 * math.pi))
    total = int(round(n_gaussians * rng.uniform(*COUNT_RANGE)))
    size_factor = float(rng.uniform(*GAUSSIAN_SIZE_RANGE))
    opacity = float(rng.uniform(*OPACITY_RANGE))
    transform = np.eye(4)
    transform[:3, :3] = scale * rotation_z(yaw)
    for piece in pieces:
        piece.mesh.apply_transform(transform)
    surface_only = realistic and draw_surface_only(rng)
    if surface_only:  # a trained capture holds only what cameras see: the whole budget goes to the surface
        for piece in pieces:
            piece.fill = False

    clouds, part_ids = [], []
    for piece, (n_surface, n_fill) in zip(pieces, allocate_counts(pieces, total)):
        cloud = mesh_to_splat(piece.mesh, n_surface, rng, fill=piece.fill and n_fill > 0, n_fill=n_fill,
                              rgb=np.asarray(piece.rgb, np.float32), color_noise=piece.color_noise,
                              opacity=opacity)
        clouds.append(cloud)
        part_ids.append(np.full(len(cloud), spec.part(piece.part).part_id, np.int32))
    for cloud in clouds:
        cloud.log_scales = (cloud.log_scales + np.float32(math.log(size_factor))).astype(np.float32)
    leftover_count = 0
    if realistic:
        lrng = leftover_rng(object_seed)
        if lrng.random() < leftover_share:
            inner = interior_leftovers([p.mesh for p in pieces], clouds, lrng)
            extra = [(c, np.full(len(c), ids[0], np.int32)) for c, ids in zip(inner, part_ids) if c is not None]
            leftover_count = sum(len(c) for c, _ in extra)
            clouds += [c for c, _ in extra]
            part_ids += [ids for _, ids in extra]
    cloud = SplatCloud.concatenate(clouds)
    part_id = np.concatenate(part_ids)
    realism, lighting = None, None
    if realistic:
        opaque = np.zeros(len(cloud), bool)
        opaque[len(cloud) - leftover_count:] = True  # the leftovers, appended last
        cloud, part_id, realism = capture_like(cloud, part_id, rng, keep_opacity=opaque)
        light_rng = lighting_rng(object_seed)
        if light_rng.random() < lighting_share:
            cloud, lighting = bake_lighting(cloud, light_rng)
    by_id = {spec.part(name).part_id: name for name in present}
    n = len(cloud)
    material = np.empty(n, np.int32)
    E, nu, rho = (np.empty(n, np.float32) for _ in range(3))
    for pid, name in by_id.items():
        sel = part_id == pid
        material[sel] = spec.part(name).material_id
        E[sel], nu[sel], rho[sel] = values[name]["E"], values[name]["nu"], values[name]["density"]
    cloud.set_materials(material, E, nu, rho)
    cloud.set("part_id", part_id, np.int32)

    extent = extent_record(cloud)
    record = {
        "class": spec.name,
        "recipe": spec.recipe,
        "seed": int(object_seed),
        "gaussians": extent["gaussians"],
        "scale": round(scale, 6),
        "yaw_rad": round(yaw, 6),
        "gaussian_size_factor": round(size_factor, 6),
        "opacity": round(opacity, 6),
        "bounds_min_m": extent["bounds_min_m"],
        "bounds_max_m": extent["bounds_max_m"],
        "rejection_draws": draws,
        "parts": [
            {"name": name, "part_id": spec.part(name).part_id, "material_id": spec.part(name).material_id,
             "E": values[name]["E"], "nu": values[name]["nu"], "density": values[name]["density"],
             "count": int((part_id == spec.part(name).part_id).sum())}
            for name in present
        ],
        "shape": shape,
    }
    if realism is not None:
        record["realism"] = {**realism.to_dict(), "surface_only": surface_only}
        if lighting is not None:
            record["realism"]["lighting"] = lighting
    return cloud, record
