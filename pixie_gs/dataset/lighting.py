"""Baked lighting: the light a capture's cameras saw, written into the Gaussians' colours.

A trained 3DGS capture stores what each surface looked like under the light of the shoot, not its paint:
leaves inside a crown are in shade, faces turned from the light are darker, glossy spots are nearly white.
The generator painted every part one palette colour plus noise, so its foliage is evenly lit and saturated
(per-Gaussian RGB spread 0.08–0.19, saturation median 0.6–0.76), where the captured plants in
../shared/real and benchmarks/real_holdout spread 0.20–0.24 with saturation medians 0.30–0.45, and read
stiff. `bake_lighting` darkens each Gaussian by ambient occlusion and a shadowed directional light and
lifts a glossy share toward white, from the geometry alone (positions and the flat Gaussians' normals);
labels are untouched. A grey sheen desaturates the paint as waxy leaves do.

Drawn from the object's own lighting RNG (`lighting_rng`), so objects that draw no lighting stay byte-identical
to those made before it existed, whatever the share.
"""
from __future__ import annotations

import math

import numpy as np

from ..prepare.gravity import flat_normals
from ..splat import SplatCloud, rgb_to_sh_dc

LIGHTING_OBJECT_SHARE = 0.5  # realistic objects whose colours carry baked lighting
LIGHTING_STREAM = 9311  # second entry of the lighting RNG's seed: [object seed, LIGHTING_STREAM]
OCCLUSION_GRID = 32  # voxels along the object's longest side for the occlusion and shadow tests
OCCLUSION_RAYS = 8  # upper-hemisphere directions per Gaussian for ambient occlusion
RAY_STEPS = 8  # voxels marched along each ray
CELL_EXTINCTION = 0.3  # light stopped by a cell: 1 − exp(−this · its Gaussians' summed opacity)
DISPLAY_GAMMA = 2.2  # sRGB-like encoding of the stored colours
SHADE_FLOOR = 0.05  # light bounced from the surroundings: no Gaussian gets less than this share of the lit faces' light
AMBIENT = (0.3, 0.7)  # share of the light that comes from the sky (the rest from one direction)
LIGHT_ELEVATION_DEG = (25.0, 80.0)
EXPOSURE = (1.0, 1.5)  # the lit faces (90th percentile of the light) shown at this factor of their paint
SHEEN = (0.0, 0.08)  # grey reflectance added to the paint's (linear), as leaves' wax or dust give
GLOSS_SHARE = 0.6  # objects with highlights
GLOSS_STRENGTH = (0.2, 0.9)
GLOSS_EXPONENT = (4.0, 40.0)


def lighting_rng(object_seed: int) -> np.random.Generator:
    """The baked lighting's own RNG for one object (independent of the object's main stream)."""
    return np.random.default_rng([int(object_seed), LIGHTING_STREAM])


def _absorption(points: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Voxel grid (OCCLUSION_GRID cells along the longest side) of the share of light each cell stops,
    1 − exp(−CELL_EXTINCTION · summed opacity of its Gaussians) (foliage lets light through its gaps, a faint
    floater hardly stops any); its origin and cell size (m)."""
    lo = points.min(0)
    cell = max(float((points.max(0) - lo).max()), 1e-9) / (OCCLUSION_GRID - 1)
    shape = np.ceil((points.max(0) - lo) / cell).astype(int) + 1
    mass = np.zeros(shape)
    idx = np.floor((points - lo) / cell).astype(int)
    np.add.at(mass, (idx[:, 0], idx[:, 1], idx[:, 2]), alpha)
    return 1.0 - np.exp(-CELL_EXTINCTION * mass), lo, cell


def _transmittance(points: np.ndarray, directions: np.ndarray, absorb: np.ndarray, lo: np.ndarray, cell: float
                   ) -> np.ndarray:
    """(n, k) share of light reaching each point along each of its k directions (n, k, 3), through RAY_STEPS
    cells starting 1.5 cells out (its own cell and neighbours skipped); beyond the grid nothing stops it."""
    through = np.ones(directions.shape[:2])
    for step in np.arange(RAY_STEPS) + 1.5:
        p = points[:, None, :] + directions * (step * cell)
        idx = np.floor((p - lo) / cell).astype(int)
        inside = np.all((idx >= 0) & (idx < np.array(absorb.shape)), axis=2)
        clipped = np.clip(idx, 0, np.array(absorb.shape) - 1)
        through *= 1.0 - inside * absorb[clipped[..., 0], clipped[..., 1], clipped[..., 2]]
    return through


def _hemisphere(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """(n, k, 3) cosine-weighted directions about +z (the sky)."""
    u, phi = rng.random((n, k)), rng.uniform(0.0, 2.0 * math.pi, (n, k))
    r = np.sqrt(u)
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - u)], axis=2)


def bake_lighting(cloud: SplatCloud, rng: np.random.Generator) -> tuple[SplatCloud, dict]:
    """Colours of `cloud` (+z up) as lit by a sky and one sun, occluded by the object itself, with sheen and
    highlights.

    In linear light (the stored colours are gamma-encoded, DISPLAY_GAMMA): irradiance E = ambient·(mean light
    through the sky rays) + (1 − ambient)·max(0, n·l)·(light through the sun ray), with n the flat Gaussian's
    normal turned away from the object's centre, scaled so that the lit faces (90th percentile) get EXPOSURE;
    radiance = (paint + sheen)·E, the sheen being the grey a waxy or dusty surface reflects whatever its paint
    (it desaturates, most in shade); on glossy objects a Blinn-Phong highlight of the sun for one view is added.
    Changes `cloud`'s colours in place (the generator lights a cloud it has just built; pass a copy to keep the
    unlit one) and returns it with a record of the draws."""
    points = cloud.means.astype(np.float64)
    n = len(points)
    alpha = 1.0 / (1.0 + np.exp(-cloud.opacity_logits.astype(np.float64)))
    absorb, lo, cell = _absorption(points, alpha)
    normal, _ = flat_normals(cloud.quats, cloud.log_scales)
    outward = points - points.mean(0)
    normal = np.where((np.sum(normal * outward, axis=1) < 0)[:, None], -normal, normal)

    ambient = float(rng.uniform(*AMBIENT))
    elevation = math.radians(rng.uniform(*LIGHT_ELEVATION_DEG))
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    sun = np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                    math.sin(elevation)])
    sky_open = _transmittance(points, _hemisphere(rng, n, OCCLUSION_RAYS), absorb, lo, cell).mean(axis=1)
    sun_open = _transmittance(points, np.broadcast_to(sun, (n, 1, 3)), absorb, lo, cell)[:, 0]
    irradiance = ambient * sky_open + (1.0 - ambient) * np.clip(normal @ sun, 0.0, None) * sun_open
    lit = max(float(np.percentile(irradiance, 90)), 0.05)  # exposed for the lit faces, as a photographer would
    irradiance = np.clip(irradiance / lit, SHADE_FLOOR, 1.0) * rng.uniform(*EXPOSURE)

    sheen = float(rng.uniform(*SHEEN))
    radiance = (cloud.rgb().astype(np.float64) ** DISPLAY_GAMMA + sheen) * irradiance[:, None]
    gloss = 0.0
    if rng.random() < GLOSS_SHARE:
        gloss = float(rng.uniform(*GLOSS_STRENGTH))
        view = _hemisphere(rng, 1, 1)[0, 0]
        view[2] = abs(view[2]) * 0.5  # cameras circle the object a little above it
        half = (sun + view / np.linalg.norm(view))
        half /= np.linalg.norm(half)
        radiance += (gloss * np.clip(normal @ half, 0.0, None) ** rng.uniform(*GLOSS_EXPONENT) * sun_open)[:, None]
    rgb = np.clip(radiance, 0.0, 1.0) ** (1.0 / DISPLAY_GAMMA)
    cloud.sh_dc = rgb_to_sh_dc(rgb.astype(np.float32)).astype(np.float32)
    record = {"ambient": round(ambient, 3), "sun_elevation_deg": round(math.degrees(elevation), 1),
              "sheen": round(sheen, 3), "gloss": round(gloss, 3),
              "irradiance_p10_p90": [round(float(v), 3) for v in np.percentile(irradiance, [10, 90])]}
    return cloud, record
