"""One forward pass: splat → feature grid → class and (log E, ν, log ρ) per voxel."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..field import DENSITY_CHANNELS, BASE_FEATURES, FeatureGrid, feature_grid
from ..materials import BACKGROUND
from ..splat import SplatCloud
from .checkpoint import LoadedModel


@dataclass
class MaterialGrid:
    """Per-voxel predictions: `classes` (N,N,N) int (BACKGROUND where unoccupied), `physical`
    (3,N,N,N) normalised (log10 E, ν, log10 ρ) in [-1, 1], `occupancy` (N,N,N) bool, the input grid."""

    classes: np.ndarray
    physical: np.ndarray
    occupancy: np.ndarray
    grid: FeatureGrid


def grid_channel_names(extra_names) -> list[str]:
    """Names of every channel of a feature grid built with these extra channels."""
    return list(DENSITY_CHANNELS + BASE_FEATURES) + list(extra_names)


def select_inputs(values, channel_names: list[str], input_channels: list[str]):
    """Pick the model's input channels (B, C_in, …) out of a full grid tensor (B, C, …)."""
    index = [channel_names.index(name) for name in input_channels]
    return values[:, index]


def classes_from_logits(logits, occupied):
    """Voxel classes: the best non-background class where occupied, BACKGROUND elsewhere (torch)."""
    import torch

    best = logits[:, :BACKGROUND].argmax(dim=1)
    return torch.where(occupied, best, torch.full_like(best, BACKGROUND))


def run_model(loaded: LoadedModel, values, channel_names: list[str], occupied):
    """(classes (B,N,N,N) long, physical (B,3,N,N,N) float32) from full grid tensors on the model's device."""
    import torch

    x = select_inputs(values, channel_names, loaded.config.input_channels)
    with torch.inference_mode():
        if x.device.type == "cuda":
            with torch.autocast("cuda", dtype=torch.bfloat16):
                logits, physical = loaded.model(x)
        else:
            logits, physical = loaded.model(x.contiguous(memory_format=torch.channels_last_3d))
    return classes_from_logits(logits.float(), occupied), physical.float().clamp(-1.5, 1.5)


def predict_materials(loaded: LoadedModel, cloud: SplatCloud, device: str = "cpu", up="z",
                      box: tuple | None = None) -> MaterialGrid:
    """Predict the material grid of `cloud` (its `up` axis or vector is turned to +z first, as in
    training; `box` (lo, hi) in that frame sets the unit-cube normalisation instead of min/max)."""
    import torch

    spec = loaded.features
    grid = feature_grid(cloud, spec.resolution, list(spec.extra_names), device=device,
                        filter_voxels=spec.filter_voxels, margin=spec.margin, up=up, box=box)
    values = torch.as_tensor(grid.values, device=device)[None]
    occupied = torch.as_tensor(grid.occupancy, device=device)[None]
    classes, physical = run_model(loaded, values, grid.channels, occupied)
    return MaterialGrid(classes=classes[0].cpu().numpy(), physical=physical[0].cpu().numpy(),
                        occupancy=grid.occupancy, grid=grid)
