"""`annotate_cloud`: predict per-Gaussian materials for a splat with a trained checkpoint.

Library entry used by `pixie annotate`, the demo and diagnose: field → U-Net → nearest-voxel
transfer, result written as `material_id`, `E` (Pa), `nu`, `density` (kg/m³) and `confidence` (0–1:
the network's class probability times an out-of-distribution factor) on a copy.

With a PreparedScene (pixie_gs/prepare), each object is predicted on its own (turned so its up
vector is +z, normalised by its robust box), background and ground become `stationary`
(held in place, stiff) and floaters are left out of every grid (written as stationary too).
"""
from __future__ import annotations

from dataclasses import dataclass
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


@dataclass
class PartPrediction:
    """One predicted material grid and what the nearest-voxel transfer needs from it (numpy).

    object_id: the prepared object it covers (None: the whole cloud); means_unit (M,3) the part's
    Gaussian centres in the grid's unit cube; classes (N,N,N), physical (3,N,N,N), occupancy and
    confidence (N,N,N) as in MaterialGrid. `mgrid` (the whole MaterialGrid with its feature grid) is
    kept in-process only: pickling (a batch sends predictions to a pool process) drops it."""

    object_id: int | None
    means_unit: np.ndarray
    classes: np.ndarray
    physical: np.ndarray
    occupancy: np.ndarray
    confidence: np.ndarray | None
    in_distribution: float
    mgrid: object = None

    @classmethod
    def of(cls, object_id: int | None, mgrid) -> "PartPrediction":
        return cls(object_id, mgrid.grid.extra["means_unit"], mgrid.classes, mgrid.physical, mgrid.occupancy,
                   mgrid.confidence, mgrid.in_distribution, mgrid)

    def __getstate__(self) -> dict:
        return {**self.__dict__, "mgrid": None}


def annotate_cloud(cloud: SplatCloud, checkpoint: str | Path | None = None, device: str = "auto",
                   up="z", return_grid: bool = False, prepared=None):
    """A copy of `cloud` with predicted materials (and the MaterialGrid when `return_grid`).

    up: axis name ("z", "-y") or unit vector; ignored when `prepared` (a PreparedScene whose
    `role`/`object_id` the cloud carries) is given: then its up and object boxes are used."""
    parts = predict_parts(cloud, checkpoint, device, up, prepared)
    out = materials_from_parts(cloud, parts, prepared)
    if not return_grid:
        return out
    return out, (parts[0].mgrid if parts else None)


def predict_parts(cloud: SplatCloud, checkpoint: str | Path | None = None, device: str = "auto", up="z",
                  prepared=None) -> list[PartPrediction]:
    """The model's part of `annotate_cloud` (field → U-Net, on `device`): one PartPrediction for the
    whole cloud, or one per prepared object (turned so its up vector is +z, normalised by its box)."""
    from .devices import resolve_torch_device
    from .field import up_rotation
    from .model.predict import predict_materials

    if prepared is None and isinstance(up, str):
        up_rotation(up)  # validates the axis name before any heavy work
    dev = resolve_torch_device(device)
    loaded = get_model(checkpoint, dev)
    if prepared is None:
        stage(f"predicting materials for {len(cloud)} Gaussians on {dev}")
        return [PartPrediction.of(None, predict_materials(loaded, cloud, dev, up))]
    n = len(cloud)
    object_id = cloud.get("object_id").astype(np.int64)
    parts = []
    for obj in prepared.objects:
        sel = np.nonzero(object_id == obj.object_id)[0]
        if len(sel) == 0:
            continue
        stage(f"predicting materials for object {obj.object_id} ({len(sel)} of {n} Gaussians) on {dev}")
        box = (np.asarray(obj.fit_box_up[0]), np.asarray(obj.fit_box_up[1]))
        parts.append(PartPrediction.of(obj.object_id, predict_materials(loaded, cloud.subset(sel), dev,
                                                                        prepared.up_vector, box=box)))
    return parts


def materials_from_parts(cloud: SplatCloud, parts: list[PartPrediction], prepared=None) -> SplatCloud:
    """The host part of `annotate_cloud`: each Gaussian takes its nearest predicted voxel's material
    and confidence; with `prepared`, everything that is not an object becomes stationary."""
    from .materials import normalize_physical
    from .transfer import write_materials

    if prepared is None:
        (part,) = parts
        mat, phys, conf = _per_gaussian(part)
        out = write_materials(cloud, mat, phys)
        out.set("confidence", conf)
        _require_finite(out, cloud.source)
        _say_confidence([(None, conf, part.in_distribution)])
        return out
    n = len(cloud)
    object_id = cloud.get("object_id").astype(np.int64)
    mat = np.full(n, STATIONARY, np.int32)
    phys = np.tile(normalize_physical(np.array([STATIONARY_E_PA]), np.array([STATIONARY_NU]),
                                      np.array([STATIONARY_DENSITY])).astype(np.float32), (n, 1))
    conf = np.ones(n, np.float32)  # background, ground and floaters: held in place by rule, not predicted
    summaries: list = []
    for part in parts:
        sel = np.nonzero(object_id == part.object_id)[0]
        m, p, c = _per_gaussian(part)
        mat[sel], phys[sel], conf[sel] = m, p, c
        summaries.append((part.object_id, c, part.in_distribution))
    out = write_materials(cloud, mat, phys)
    out.set("confidence", conf)
    _require_finite(out, cloud.source)
    _say_confidence(summaries)
    return out


def _require_finite(out: SplatCloud, source: str | None) -> None:
    """ComputationError (exit 3) when a prediction is NaN/inf: never written, never reported as success."""
    from .errors import require_finite_result

    require_finite_result({name: out.get(name) for name in ("E", "nu", "density", "confidence")},
                          "predicted materials", source)


def _per_gaussian(mgrid: PartPrediction) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(material_id, normalised physical, confidence) per Gaussian from its nearest material voxel."""
    from .transfer import nearest_voxel_index

    vox = nearest_voxel_index(mgrid.means_unit, mgrid.classes, mgrid.occupancy)
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
