"""Material ids, names and the normalisation of (E, ν, ρ) shared by the dataset, model and simulator.

Ids follow the Pixie/PhysGaussian MPM: 0 jelly, 1 metal, 2 sand, 3 visco-plastic, 4 fluid,
5 snow, 6 stationary; the U-Net adds 7 = background (empty voxel).
Normalisation ranges are the public Pixie dataset statistics (log10 ρ in kg/m³, log10 E in Pa).
"""
from __future__ import annotations

import numpy as np

JELLY, METAL, SAND, VISCOPLASTIC, FLUID, SNOW, STATIONARY, BACKGROUND = range(8)
NUM_CLASSES = 8

MATERIAL_NAMES: dict[int, str] = {
    JELLY: "jelly",
    METAL: "metal",
    SAND: "sand",
    VISCOPLASTIC: "visco-plastic",
    FLUID: "fluid",
    SNOW: "snow",
    STATIONARY: "stationary",
    BACKGROUND: "background",
}

# Display colours (RGB in [0, 1]) for pictures and rerun recordings, one per material id.
MATERIAL_COLORS = np.array(
    [
        [0.90, 0.35, 0.55],  # jelly
        [0.60, 0.65, 0.75],  # metal
        [0.90, 0.75, 0.40],  # sand
        [0.55, 0.35, 0.80],  # visco-plastic
        [0.25, 0.55, 0.95],  # fluid
        [0.95, 0.95, 1.00],  # snow
        [0.30, 0.30, 0.30],  # stationary
        [0.00, 0.00, 0.00],  # background
    ],
    dtype=np.float32,
)

LOG10_E_RANGE = (3.018, 10.882)  # log10 Pa
NU_RANGE = (0.210, 0.449)
LOG10_DENSITY_RANGE = (1.703, 3.871)  # log10 kg/m³


def _to_unit(v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return 2.0 * (v - lo) / (hi - lo) - 1.0


def _from_unit(u: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (u + 1.0) * 0.5 * (hi - lo) + lo


def normalize_physical(E_pa: np.ndarray, nu: np.ndarray, density_kg_m3: np.ndarray) -> np.ndarray:
    """Map SI (E Pa, ν, ρ kg/m³) to the model's normalised targets in [-1, 1], shape (..., 3)."""
    return np.stack(
        [
            _to_unit(np.log10(np.asarray(E_pa, dtype=np.float64)), *LOG10_E_RANGE),
            _to_unit(np.asarray(nu, dtype=np.float64), *NU_RANGE),
            _to_unit(np.log10(np.asarray(density_kg_m3, dtype=np.float64)), *LOG10_DENSITY_RANGE),
        ],
        axis=-1,
    ).astype(np.float32)


def denormalize_physical(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of `normalize_physical`: (..., 3) normalised values → (E Pa, ν, ρ kg/m³)."""
    values = np.asarray(values, dtype=np.float64)
    E = 10.0 ** _from_unit(values[..., 0], *LOG10_E_RANGE)
    nu = _from_unit(values[..., 1], *NU_RANGE)
    rho = 10.0 ** _from_unit(values[..., 2], *LOG10_DENSITY_RANGE)
    return E.astype(np.float32), nu.astype(np.float32), rho.astype(np.float32)
