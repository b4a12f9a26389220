"""Labelled objects for training/evaluation as compact per-Gaussian arrays, and the GPU-side store.

An object is read once (SplatCloud via the dataset loader), reduced to what the field and the
labels need (world means and covariances, opacity, RGB, SH energy, extra channels, material id and
normalised (log10 E, ν, log10 ρ)), and kept in memory, so each training batch can re-augment the
Gaussians and rebuild its grids on the device instead of reading files again.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..field import extra_feature_names, per_gaussian_channels
from ..materials import normalize_physical
from ..progress import progress
from ..splat import SplatCloud


@dataclass
class ObjectRecord:
    """One labelled object as float32/int arrays (M Gaussians) plus its class name."""

    name: str
    class_name: str
    means: np.ndarray  # (M,3) file units
    covariances: np.ndarray  # (M,3,3)
    alphas: np.ndarray  # (M,)
    rgb: np.ndarray  # (M,3)
    sh_energy: np.ndarray  # (M,)
    extras: np.ndarray  # (M,E)
    material_id: np.ndarray  # (M,) int64
    physical: np.ndarray  # (M,3) normalised


def record_from_cloud(cloud: SplatCloud, extra_names: list[str], name: str = "", class_name: str = "") -> ObjectRecord:
    """Compact arrays of a labelled cloud (InputError when labels are missing)."""
    mid, E, nu, rho = cloud.get_materials()
    sh, extras = per_gaussian_channels(cloud, extra_names)
    return ObjectRecord(name, class_name, cloud.means.astype(np.float32), cloud.covariances().astype(np.float32),
                        cloud.opacities.astype(np.float32), cloud.rgb(), sh.astype(np.float32), extras,
                        mid.astype(np.int64), normalize_physical(E, nu, rho))


def _load_one(args: tuple[str, list[str] | None]) -> tuple[ObjectRecord, list[str]]:
    from ..dataset.loader import load_object

    path, extra_names = args
    cloud, meta = load_object(path)
    names = extra_feature_names(cloud) if extra_names is None else extra_names
    return record_from_cloud(cloud, names, Path(path).stem, str(meta.get("class", ""))), names


def split_paths(data_dir: str | Path, split: str) -> list[Path]:
    """The object files of `split` (dataset index order)."""
    from ..dataset.loader import list_objects

    paths = list_objects(data_dir, split)
    if not paths:
        raise InputError(f"the '{split}' split has no objects", data_dir)
    return paths


def load_split(data_dir: str | Path, split: str, extra_names: list[str] | None = None, limit: int | None = None,
               workers: int = 1) -> tuple[list[ObjectRecord], list[str]]:
    """All objects of a split as ObjectRecords, and the extra channel names used.

    With `extra_names` None, the extra float channels of the first object define the set (every
    object must then carry them; missing ones read as zeros).
    """
    paths = split_paths(data_dir, split)[: limit or None]
    if extra_names is None:
        _, extra_names = _load_one((str(paths[0]), None))
    jobs = [(str(p), list(extra_names)) for p in paths]
    if workers > 1 and len(jobs) > 1:
        import multiprocessing

        with multiprocessing.get_context("spawn").Pool(min(workers, len(jobs))) as pool:
            out = list(progress(pool.imap(_load_one, jobs, chunksize=4), f"load {split}", total=len(jobs), unit="obj"))
    else:
        out = [_load_one(j) for j in progress(jobs, f"load {split}", total=len(jobs), unit="obj")]
    return [r for r, _ in out], list(extra_names)


class DeviceStore:
    """Every object's arrays concatenated into device tensors, sliced per object by offsets."""

    FIELDS = ("means", "covariances", "alphas", "rgb", "sh_energy", "extras", "material_id", "physical")

    def __init__(self, records: list[ObjectRecord], device: str) -> None:
        import torch

        self.device = device
        self.names = [r.name for r in records]
        self.class_names = [r.class_name for r in records]
        counts = np.array([len(r.alphas) for r in records])
        self.offsets = np.concatenate([[0], np.cumsum(counts)])
        self.tensors = {}
        for f in self.FIELDS:
            arr = np.concatenate([getattr(r, f) for r in records])
            dtype = torch.long if f == "material_id" else torch.float32
            self.tensors[f] = torch.as_tensor(arr, dtype=dtype, device=device)

    def __len__(self) -> int:
        return len(self.names)

    def object(self, i: int) -> dict:
        a, b = int(self.offsets[i]), int(self.offsets[i + 1])
        return {f: t[a:b] for f, t in self.tensors.items()}
