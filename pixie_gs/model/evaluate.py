"""Evaluate a checkpoint on a held-out split: per occupied voxel and per Gaussian (after transfer)."""
from __future__ import annotations

from pathlib import Path

from ..progress import progress
from ..transfer import nearest_voxel_values
from .batch import build_batch
from .checkpoint import LoadedModel
from .label_floor import split_floor
from .metrics import MetricAccumulator
from .predict import grid_channel_names, run_model


def evaluation_batches(loaded: LoadedModel, store, batch_size: int = 4, desc: str = "evaluate"):
    """Yield (object indices, batch, classes (B,N,N,N), physical (B,3,N,N,N)): the model's outputs on every
    object of a DeviceStore, batch by batch (no augmentation), with a progress bar."""
    names = grid_channel_names(loaded.features.extra_names)
    ids = list(range(len(store)))
    chunks = [ids[i:i + batch_size] for i in range(0, len(ids), batch_size)]
    for chunk in progress(chunks, desc, total=len(chunks), unit="batch"):
        batch = build_batch(store, chunk, loaded.features)
        classes, physical = run_model(loaded, batch.inputs, names, batch.occupied)
        yield chunk, batch, classes, physical


def gaussian_values(batch, b: int, classes, physical):
    """(material id (M,), normalised physical (M,3)) of batch item `b`'s Gaussians, each from its nearest
    occupied voxel, as `annotate` transfers them."""
    return nearest_voxel_values(batch.means_unit[b].cpu().numpy(), classes[b].cpu().numpy(),
                                physical[b].cpu().numpy(), batch.occupied[b].cpu().numpy())


def evaluate_store(loaded: LoadedModel, store, batch_size: int = 4, per_gaussian: bool = True,
                   desc: str = "evaluate") -> dict:
    """Metrics of `loaded` over every object of a DeviceStore (no augmentation)."""
    acc = MetricAccumulator()
    for chunk, batch, classes, physical in evaluation_batches(loaded, store, batch_size, desc):
        acc.add_voxels(classes, physical, batch.target_class, batch.target_physical, batch.occupied)
        if per_gaussian:
            for b, i in enumerate(chunk):
                obj = store.object(i)
                mat, phys = gaussian_values(batch, b, classes, physical)
                acc.add_gaussians(mat, phys, obj["material_id"].cpu().numpy(), obj["physical"].cpu().numpy(),
                                  store.class_names[i])
    return acc.summary()


def evaluate_split(loaded: LoadedModel, data_dir: str | Path, split: str = "test", device: str = "cpu",
                   limit: int | None = None, workers: int = 1, batch_size: int = 4) -> dict:
    """Load `split` of `data_dir` and evaluate `loaded` on it; with the split's label floor (the MSE no
    model can remove: model/label_floor.py) when its records match the installed class table."""
    from .data import DeviceStore, load_split

    records, _ = load_split(data_dir, split, list(loaded.features.extra_names), limit, workers)
    store = DeviceStore(records, device)
    summary = evaluate_store(loaded, store, batch_size)
    floor = split_floor(data_dir, split, limit)
    if floor is not None:
        summary["label_floor"] = floor
    summary["split"] = split
    summary["checkpoint"] = loaded.path
    return summary
