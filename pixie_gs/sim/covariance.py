"""Gaussian covariances follow the deformation: Σ' = F Σ Fᵀ (PhysGaussian)."""
from __future__ import annotations

import numpy as np


def advect_covariances(cov0: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Deformed covariances (N,3,3) m² from rest covariances cov0 (N,3,3) and F (N,3,3).

    Computed in float64 and symmetrised (FΣFᵀ is symmetric in exact arithmetic); returned as float32.
    """
    cov0 = np.asarray(cov0, dtype=np.float64)
    F = np.asarray(F, dtype=np.float64)
    if cov0.shape != F.shape or cov0.shape[1:] != (3, 3):
        raise ValueError(f"advect_covariances needs matching (N,3,3) arrays, got {cov0.shape} and {F.shape}")
    cov = F @ cov0 @ np.transpose(F, (0, 2, 1))
    return (0.5 * (cov + np.transpose(cov, (0, 2, 1)))).astype(np.float32)
