"""`annotate_cloud`: predict per-Gaussian materials for a splat with a trained checkpoint.

Library entry used by `pixie annotate`, the demo and diagnose: field → U-Net → nearest-voxel
transfer, result written as `material_id`, `E` (Pa), `nu`, `density` (kg/m³) on a copy.
"""
from __future__ import annotations

from pathlib import Path

from .errors import require_finite_result
from .progress import stage
from .splat import SplatCloud

_CACHE: dict[tuple[str, str], object] = {}


def get_model(checkpoint: str | Path | None = None, device: str = "cpu"):
    """Load (once per process) the checkpoint on `device`; None means the shipped default."""
    from .model.checkpoint import DEFAULT_CHECKPOINT, load_checkpoint

    key = (str(Path(checkpoint).resolve()) if checkpoint else str(DEFAULT_CHECKPOINT), device)
    if key not in _CACHE:
        _CACHE[key] = load_checkpoint(checkpoint, device)
    return _CACHE[key]


def annotate_cloud(cloud: SplatCloud, checkpoint: str | Path | None = None, device: str = "auto",
                   up: str = "z", return_grid: bool = False):
    """A copy of `cloud` with predicted materials (and the MaterialGrid when `return_grid`)."""
    from .devices import resolve_torch_device
    from .field import up_rotation
    from .model.predict import predict_materials
    from .transfer import nearest_voxel_values, write_materials

    up_rotation(up)  # validates the axis name before any heavy work
    dev = resolve_torch_device(device)
    loaded = get_model(checkpoint, dev)
    stage(f"predicting materials for {len(cloud)} Gaussians on {dev}")
    mgrid = predict_materials(loaded, cloud, dev, up)
    mat, phys = nearest_voxel_values(mgrid.grid.extra["means_unit"], mgrid.classes, mgrid.physical,
                                     mgrid.occupancy)
    out = write_materials(cloud, mat, phys)
    require_finite_result({name: out.get(name) for name in ("E", "nu", "density")}, "predicted materials",
                          cloud.source)
    return (out, mgrid) if return_grid else out
