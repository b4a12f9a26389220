"""Which training objects pull a reading of the network, and which way: first-order data attribution.

A fine-tune step on object o moves the weights by −η g_o (g_o = ∇θ loss(o)), so a reading r(θ) of some other
splat (say the mean predicted log E over a real capture's dough) changes by ≈ −η ∇r · g_o. The cosine of
−g_o with ∇r says whether training on o pushes the reading up or down, independently of the step size
(TracIn, Pruthi et al. 2020, at one checkpoint). Why: every fine-tune so far moved the same few real-capture
readings (docs/model_card.md, r40–r44); this names the generated categories that pull them, so a data mix
can be chosen before GPU time is spent (scripts/real_reading_attribution.py).

Readings are means of the raw physical head (normalised log10 E, ν, log10 ρ in [−1, 1], before the label-range
clamp, whose gradient is zero outside) over the voxels holding a chosen set of Gaussians, on the grid
`feature_grid` builds; the loss is the training loss (`train.batch_loss`, no augmentation).
"""
from __future__ import annotations

import numpy as np

from ..field import feature_grid
from ..splat import SplatCloud
from .batch import build_batch
from .checkpoint import LoadedModel
from .predict import grid_channel_names, model_inputs

QUANTITIES = ("log_E", "nu", "log_rho")  # the physical head's channels, in order


def _trainable(loaded: LoadedModel) -> list:
    """The network's parameters, gradients on, in eval mode (no dropout; GroupNorm has no running state)."""
    net = loaded.model.float().eval()
    params = list(net.parameters())
    for p in params:
        p.requires_grad_(True)
    return params


def _flat_grad(params: list):
    import torch

    return torch.cat([(p.grad if p.grad is not None else torch.zeros_like(p)).reshape(-1) for p in params])


def reading_gradient(loaded: LoadedModel, cloud: SplatCloud, up, selected: np.ndarray, quantity: str
                     ) -> tuple[float, "object"]:
    """(reading, ∇θ reading as one flat tensor): the mean of `quantity` (one of QUANTITIES, normalised units)
    over the voxels that hold the Gaussians `selected` (bool mask over `cloud`, each Gaussian's nearest voxel
    counted once per Gaussian), with `cloud` turned by `up` (axis name or vector) as `annotate` does."""
    import torch

    if quantity not in QUANTITIES:
        raise ValueError(f"quantity must be one of {QUANTITIES}")
    selected = np.asarray(selected, bool)
    if not selected.any():
        raise ValueError("no Gaussians selected for the reading")
    spec = loaded.features
    grid = feature_grid(cloud, spec.resolution, list(spec.extra_names), device="cpu",
                        filter_voxels=spec.filter_voxels, margin=spec.margin, up=up)
    n = spec.resolution
    vox = np.clip((grid.extra["means_unit"][selected] * n).astype(np.int64), 0, n - 1)
    flat = torch.as_tensor(vox[:, 0] * n * n + vox[:, 1] * n + vox[:, 2])
    x = model_inputs(loaded, torch.as_tensor(grid.values)[None], grid.channels)  # as inference builds it
    params = _trainable(loaded)
    loaded.model.zero_grad(set_to_none=True)
    _, physical = loaded.model(x)
    reading = physical[0, QUANTITIES.index(quantity)].reshape(-1)[flat].mean()
    reading.backward()
    return float(reading.detach()), _flat_grad(params)


def loss_gradient(loaded: LoadedModel, store, ids: list[int]):
    """∇θ of the training loss (no augmentation) on objects `ids` of a DeviceStore, one flat tensor."""
    from .train import batch_loss

    params = _trainable(loaded)
    names = grid_channel_names(list(loaded.features.extra_names))
    batch = build_batch(store, list(ids), loaded.features)
    loaded.model.zero_grad(set_to_none=True)
    loss, _, _ = batch_loss(loaded.model, batch, True, names, loaded.config.input_channels, 1.0, False)
    loss.backward()
    return _flat_grad(params)


def step_cosine(reading_grad, loss_grad) -> float:
    """cos(∇r, −g): > 0 when a descent step on the loss raises the reading, < 0 when it lowers it."""
    denom = float(reading_grad.norm() * loss_grad.norm())
    return 0.0 if denom == 0.0 else float(-(reading_grad @ loss_grad)) / denom
