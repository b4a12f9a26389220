"""Interior leftovers: large opaque Gaussians inside a captured object, as trained 3DGS files often hold.

3DGS starts from points spread through the scene (random points in a box for synthetic scenes, an SfM
cloud for real ones). Points that end up inside an opaque object are hidden behind its surface, so no
view asks them to shrink, fade or go; they stay, often large and opaque. The real donut capture of the
development set (`../shared/real/orig/donut_fused.ply`) is like this: 20 % of its Gaussians have
σ_max > 6 mm (of a 21 cm object), sit inside the ring's tube with median opacity 0.96, and fill the
feature grid's tube solid; r39 reads it at E ≈ 2e8 Pa, and at ≈ 3e4 Pa with them removed. The
generator drew only surfaces (85 %) or small fill Gaussians (15 %), so solid grids of large Gaussians
came only from a few stiff categories. Here a share of realistic objects of every category gets such
leftovers, so that they say nothing about the material.

Drawn from a separate RNG seeded by the object's seed, so objects without leftovers stay byte-identical
to what the generator made before this came in.
"""
from __future__ import annotations

import numpy as np

from ..convert import is_closed, sample_interior
from ..errors import InputError
from ..splat import SplatCloud, rotmat_to_quat
from .primitives import random_rotation

LEFTOVER_OBJECT_SHARE = 0.3  # realistic objects that hold interior leftovers
LEFTOVER_COUNT_SHARE = (0.05, 0.3)  # their number, as a share of the object's other Gaussians
LEFTOVER_SIGMA_REL = (0.01, 0.05)  # σ_max over the object's box diagonal (log-uniform; the donut: q50 0.03)
LEFTOVER_MID_RATIO = (0.2, 0.6)  # σ_mid / σ_max: flat discs, as in the capture
LEFTOVER_MIN_RATIO = (0.02, 0.1)  # σ_min / σ_max
LEFTOVER_OPACITY_LOGIT = (2.5, 1.5)  # mean, std-dev of their opacity logit (median α ≈ 0.92)
LEFTOVER_STREAM = 7177  # second entry of the leftover RNG's seed: [object seed, LEFTOVER_STREAM]


def leftover_rng(object_seed: int) -> np.random.Generator:
    """The leftovers' own RNG for one object (independent of the object's main stream)."""
    return np.random.default_rng([int(object_seed), LEFTOVER_STREAM])


def interior_leftovers(meshes: list, surface: list[SplatCloud], rng: np.random.Generator
                       ) -> list[SplatCloud | None]:
    """Per piece, a cloud of interior leftovers (None where the piece gets none or is not closed).

    meshes: the pieces' meshes in metres, as placed; surface: each piece's Gaussians (their colours and
    extra properties are copied from the nearest one). The caller decides whether the object gets any.
    """
    from scipy.spatial import cKDTree

    lo = np.min([np.asarray(m.bounds[0]) for m in meshes], 0)
    hi = np.max([np.asarray(m.bounds[1]) for m in meshes], 0)
    diagonal = float(np.linalg.norm(hi - lo))
    share = float(rng.uniform(*LEFTOVER_COUNT_SHARE))
    out: list[SplatCloud | None] = []
    for mesh, cloud in zip(meshes, surface):
        count = int(round(share * len(cloud)))
        if count < 1 or not is_closed(mesh):
            out.append(None)
            continue
        try:
            points = sample_interior(mesh, count, rng)
        except InputError:  # closed in topology but with next to no volume (a thin or degenerate piece)
            out.append(None)
            continue
        _, nearest = cKDTree(cloud.means).query(points, k=1)
        inner = cloud.subset(nearest)
        inner.means = points.astype(np.float32)
        s_max = diagonal * np.exp(rng.uniform(*np.log(LEFTOVER_SIGMA_REL), count))
        sigma = np.stack([s_max, s_max * rng.uniform(*LEFTOVER_MID_RATIO, count),
                          s_max * rng.uniform(*LEFTOVER_MIN_RATIO, count)], 1)
        inner.log_scales = np.log(sigma).astype(np.float32)
        inner.rotations = rotmat_to_quat(random_rotation(rng, count)).astype(np.float32)
        inner.opacity_logits = rng.normal(*LEFTOVER_OPACITY_LOGIT, count).astype(np.float32)
        for name in ("nx", "ny", "nz"):
            if inner.has(name):
                inner.set(name, np.zeros(count, np.float32))
        out.append(inner)
    return out
