"""Voxel predictions → per-Gaussian materials: each Gaussian takes the nearest predicted voxel.

Only occupied voxels whose predicted class is a real material are candidates, so a Gaussian is
never assigned background (id 7), even when it sits in an empty voxel (faint or tiny Gaussians).
"""
from __future__ import annotations

import numpy as np

from .errors import ComputationError
from .materials import BACKGROUND, denormalize_physical
from .splat import SplatCloud


def nearest_voxel_index(points_unit: np.ndarray, classes: np.ndarray, occupancy: np.ndarray) -> np.ndarray:
    """(M,3) int voxel index of the nearest occupied material voxel for points (M,3) in the unit cube.

    `classes` (N,N,N) and `occupancy` (N,N,N) bool on the grid over [0,1]³."""
    n = classes.shape[0]
    candidates = occupancy & (classes != BACKGROUND) & (classes >= 0)
    if not candidates.any():
        raise ComputationError("the model found no occupied voxel with a material; "
                               "is the splat empty or fully transparent?")
    pts = np.asarray(points_unit, dtype=np.float64)
    # The nearest voxel centre to a point is the voxel containing it, so a point inside a candidate
    # voxel takes that voxel directly; only the others need the KD-tree over candidate centres.
    vox = np.clip(np.floor(pts * n).astype(np.int64), 0, n - 1)
    outside = ~candidates[vox[:, 0], vox[:, 1], vox[:, 2]] | (pts < 0).any(1) | (pts >= 1).any(1)
    if outside.any():
        from scipy.spatial import cKDTree  # imported only when needed (~0.7 s)

        idx = np.argwhere(candidates)
        _, nearest = cKDTree((idx + 0.5) / n).query(pts[outside], k=1)
        vox[outside] = idx[nearest]
    return vox


def nearest_voxel_values(points_unit: np.ndarray, classes: np.ndarray, physical: np.ndarray,
                         occupancy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(material_id (M,) int32, normalised physical (M,3)) for points (M,3) in the unit cube.

    `classes` (N,N,N), `physical` (3,N,N,N), `occupancy` (N,N,N) bool on the grid over [0,1]³.
    """
    vox = nearest_voxel_index(points_unit, classes, occupancy)
    mat = classes[vox[:, 0], vox[:, 1], vox[:, 2]].astype(np.int32)
    phys = physical[:, vox[:, 0], vox[:, 1], vox[:, 2]].T.astype(np.float32)
    return mat, phys


def write_materials(cloud: SplatCloud, material_id: np.ndarray, physical_normalised: np.ndarray) -> SplatCloud:
    """A copy of `cloud` with material_id, E (Pa), nu, density (kg/m³) set from normalised values."""
    E, nu, rho = denormalize_physical(physical_normalised)
    out = cloud.copy()
    out.set_materials(material_id, E, nu, rho)
    return out
