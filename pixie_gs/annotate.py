"""`annotate_cloud`: predict per-Gaussian materials for a splat with a trained checkpoint.

Library entry used by `pixie annotate`, the demo and diagnose: field → U-Net → nearest-voxel
transfer, result written as `material_id`, `E` (Pa), `nu`, `density` (kg/m³) and `confidence` (0–1:
the network's class probability times an out-of-distribution factor) on a copy.

With a PreparedScene (pixie_gs/prepare), each object is predicted on its own (turned so its up
vector is +z, normalised by its robust box), background and ground become `stationary`
(held in place, stiff) and floaters are left out of every grid (written as stationary too).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .progress import stage
from .splat import SplatCloud

_CACHE: dict[tuple[str, str], object] = {}
STATIONARY = 6
# Values written for background, ground and floater Gaussians: rigid and held in place.
STATIONARY_E_PA = 1.0e9
STATIONARY_NU = 0.3
STATIONARY_DENSITY = 1500.0


def get_model(checkpoint: str | Path | None = None, device: str = "cpu"):
    """Load (once per process) the checkpoint on `device`; None means the shipped default."""
    from .model.checkpoint import DEFAULT_CHECKPOINT, load_checkpoint

    key = (str(Path(checkpoint).resolve()) if checkpoint else str(DEFAULT_CHECKPOINT), device)
    if key not in _CACHE:
        _CACHE[key] = load_checkpoint(checkpoint, device)
    return _CACHE[key]


def annotate_cloud(cloud: SplatCloud, checkpoint: str | Path | None = None, device: str = "auto",
                   up="z", return_grid: bool = False, prepared=None):
    """A copy of `cloud` with predicted materials (and the MaterialGrid when `return_grid`).

    up: axis name ("z", "-y") or unit vector; ignored when `prepared` (a PreparedScene whose
    `role`/`object_id` the cloud carries) is given: then its up and object boxes are used."""
    from .devices import resolve_torch_device
    from .field import up_rotation
    from .model.predict import predict_materials
    from .transfer import write_materials

    if prepared is None and isinstance(up, str):
        up_rotation(up)  # validates the axis name before any heavy work
    dev = resolve_torch_device(device)
    loaded = get_model(checkpoint, dev)
    if prepared is None:
        stage(f"predicting materials for {len(cloud)} Gaussians on {dev}")
        mgrid = predict_materials(loaded, cloud, dev, up)
        mat, phys, conf = _per_gaussian(mgrid)
        out = write_materials(cloud, mat, phys)
        out.set("confidence", conf)
        _require_finite(out, cloud.source)
        _say_confidence([(None, conf, mgrid.in_distribution)])
        return (out, mgrid) if return_grid else out
    return _annotate_prepared(cloud, loaded, dev, prepared, return_grid)


def _annotate_prepared(cloud: SplatCloud, loaded, dev: str, prepared, return_grid: bool):
    """Per-object prediction; everything that is not an object becomes stationary."""
    from .materials import normalize_physical
    from .model.predict import predict_materials
    from .transfer import write_materials

    n = len(cloud)
    object_id = cloud.get("object_id").astype(np.int64)
    mat = np.full(n, STATIONARY, np.int32)
    phys = np.tile(normalize_physical(np.array([STATIONARY_E_PA]), np.array([STATIONARY_NU]),
                                      np.array([STATIONARY_DENSITY])).astype(np.float32), (n, 1))
    conf = np.ones(n, np.float32)  # background, ground and floaters: held in place by rule, not predicted
    summaries: list = []
    first_grid = None
    up = prepared.up_vector
    for obj in prepared.objects:
        sel = np.nonzero(object_id == obj.object_id)[0]
        if len(sel) == 0:
            continue
        stage(f"predicting materials for object {obj.object_id} ({len(sel)} of {n} Gaussians) on {dev}")
        part = cloud.subset(sel)
        box = (np.asarray(obj.fit_box_up[0]), np.asarray(obj.fit_box_up[1]))
        mgrid = predict_materials(loaded, part, dev, up, box=box)
        m, p, c = _per_gaussian(mgrid)
        mat[sel], phys[sel], conf[sel] = m, p, c
        summaries.append((obj.object_id, c, mgrid.in_distribution))
        first_grid = first_grid or mgrid
    out = write_materials(cloud, mat, phys)
    out.set("confidence", conf)
    _require_finite(out, cloud.source)
    _say_confidence(summaries)
    return (out, first_grid) if return_grid else out


def _require_finite(out: SplatCloud, source: str | None) -> None:
    """ComputationError (exit 3) when a prediction is NaN/inf: never written, never reported as success."""
    from .errors import require_finite_result

    require_finite_result({name: out.get(name) for name in ("E", "nu", "density", "confidence")},
                          "predicted materials", source)


def _per_gaussian(mgrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(material_id, normalised physical, confidence) per Gaussian from its nearest material voxel."""
    from .transfer import nearest_voxel_index

    vox = nearest_voxel_index(mgrid.grid.extra["means_unit"], mgrid.classes, mgrid.occupancy)
    i, j, k = vox[:, 0], vox[:, 1], vox[:, 2]
    conf = (mgrid.confidence[i, j, k] if mgrid.confidence is not None else np.ones(len(vox))).astype(np.float32)
    return (mgrid.classes[i, j, k].astype(np.int32), mgrid.physical[:, i, j, k].T.astype(np.float32), conf)


def _say_confidence(summaries: list[tuple[object, np.ndarray, float]]) -> None:
    """One stage line per object: mean confidence, and a warning when the materials are a guess."""
    from .model.predict import GUESS_THRESHOLD

    for object_id, conf, ind in summaries:
        name = "object" if object_id is None else f"object {object_id}"
        mean = float(np.mean(conf)) if len(conf) else 0.0
        line = f"{name}: mean material confidence {mean:.2f} (in-distribution {ind:.2f})"
        if mean < GUESS_THRESHOLD:
            line += f"; {name} looks unlike the training data: treat its materials as a guess"
        stage(line)
