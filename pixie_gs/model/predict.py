"""One forward pass: splat → feature grid → class and (log E, ν, log ρ) per voxel."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..field import DENSITY_CHANNELS, BASE_FEATURES, FeatureGrid, feature_grid
from ..materials import BACKGROUND, LOG10_DENSITY_RANGE, LOG10_E_RANGE, NU_RANGE, normalize_physical
from ..splat import SplatCloud

if TYPE_CHECKING:  # checkpoint imports torch; batch pool processes import this module for GUESS_THRESHOLD only
    from .checkpoint import LoadedModel


@dataclass
class MaterialGrid:
    """Per-voxel predictions: `classes` (N,N,N) int (BACKGROUND where unoccupied), `physical`
    (3,N,N,N) normalised (log10 E, ν, log10 ρ) in [-1, 1], `occupancy` (N,N,N) bool, the input grid,
    and how far to trust them (`confidence`, `in_distribution`; see `voxel_confidence`)."""

    classes: np.ndarray
    physical: np.ndarray
    occupancy: np.ndarray
    grid: FeatureGrid
    confidence: np.ndarray | None = None  # (N,N,N) class probability × in_distribution, in [0, 1]
    in_distribution: float = 1.0  # 1: the object's grid statistics look like the training objects'


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


# Physical limits of any prediction: ν stays below this even if a checkpoint's label range says otherwise.
NU_MAX = 0.49
LABEL_KEYS = ("log10_E_pa", "nu", "log10_density_kg_m3")


def default_label_ranges() -> dict[str, list[float]]:
    """Label ranges for checkpoints that store none: the public Pixie statistics (materials.py)."""
    return {"log10_E_pa": list(LOG10_E_RANGE), "nu": list(NU_RANGE), "log10_density_kg_m3": list(LOG10_DENSITY_RANGE)}


def label_ranges(meta: dict) -> dict[str, list[float]]:
    """The (low, high) label ranges a checkpoint's outputs are clamped to: `meta["label_ranges"]` when
    it is well formed (log10 E Pa, ν, log10 ρ kg/m³), else the public statistics. ν is capped at NU_MAX."""
    out = default_label_ranges()
    raw = meta.get("label_ranges") if isinstance(meta, dict) else None
    if isinstance(raw, dict):
        for key in LABEL_KEYS:
            v = raw.get(key)
            if (isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v)
                    and np.all(np.isfinite(v)) and v[0] <= v[1]):
                out[key] = [float(v[0]), float(v[1])]
    out["nu"] = [min(out["nu"][0], NU_MAX), min(out["nu"][1], NU_MAX)]
    return out


def normalised_bounds(meta: dict) -> tuple[np.ndarray, np.ndarray]:
    """(low (3,), high (3,)) of the label ranges in the model's normalised units."""
    r = label_ranges(meta)
    lo = normalize_physical(10.0 ** r["log10_E_pa"][0], r["nu"][0], 10.0 ** r["log10_density_kg_m3"][0])
    hi = normalize_physical(10.0 ** r["log10_E_pa"][1], r["nu"][1], 10.0 ** r["log10_density_kg_m3"][1])
    return lo.astype(np.float32), hi.astype(np.float32)


# In-distribution score: RMS z-score d of an object's grid statistics against the training objects';
# exp(-½ ((d - OOD_FREE_Z) / OOD_WIDTH)²) above OOD_FREE_Z, 1 below. Set on generated held-out objects
# (d 0.5–1.6, most ≤ 1) vs out-of-vocabulary ones (d 1.2–2.4); see docs/model_card.md "Confidence".
OOD_FREE_Z = 1.0
OOD_WIDTH = 0.35
GUESS_THRESHOLD = 0.5  # mean confidence under which annotate calls the materials a guess


def object_feature_summary(values, occupied):
    """(B, C+1) per-object statistics of full grid tensors: the mean of every channel over occupied
    voxels and log10 of the occupied share. Used for the out-of-distribution score."""
    import torch

    occ = occupied.float()
    count = occ.flatten(1).sum(1).clamp_min(1.0)
    means = (values.float() * occ[:, None]).flatten(2).sum(2) / count[:, None]
    share = torch.log10(count / occ[0].numel())
    return torch.cat([means, share[:, None]], 1)


def untrained_channels(meta: dict) -> list[str]:
    """Grid channels that were zero on every training object (mean and std 0 in meta["feature_stats"]).

    The network never saw them vary, so its response to them is untrained: inference holds them at zero
    as in training, and the in-distribution score leaves them out. Example: `sh_energy` (‖f_rest‖) for a
    checkpoint trained on degree-0 splats, where any view-dependent colour used to flip classes."""
    stats = meta.get("feature_stats") if isinstance(meta, dict) else None
    try:
        names, mean, std = list(stats["channels"]), list(stats["mean"]), list(stats["std"])
    except (TypeError, KeyError):
        return []
    return [n for n, m, s in zip(names, mean, std) if m == 0 and s == 0]


def in_distribution_score(meta: dict, summary: np.ndarray) -> float:
    """1 when an object's `object_feature_summary` lies within OOD_FREE_Z (RMS z-score) of the training
    objects' statistics stored in the checkpoint (meta["feature_stats"]), decaying beyond; 1 for a
    checkpoint without statistics. With `groups` there (one per look of training object: capture-like,
    clean; model/stats.py `--by-look`) the distance is the smallest to the pooled statistics or any group:
    a clean converted mesh sits far from the pooled middle of mostly capture-like objects, but near the
    clean group."""
    stats = meta.get("feature_stats") if isinstance(meta, dict) else None
    if not isinstance(stats, dict):
        return 1.0
    f = np.asarray(summary, np.float64).reshape(-1)
    untrained = set(untrained_channels(meta))
    keep = np.array([n not in untrained for n in stats.get("channels", [])] or [True] * len(f))
    if keep.shape != f.shape:
        keep = np.ones(len(f), bool)
    groups = stats.get("groups") if isinstance(stats.get("groups"), list) else []
    described = [stats] + [g for g in groups if isinstance(g, dict)]
    distances = [d for d in (_rms_z(g, f, keep) for g in described) if d is not None]
    if not distances:
        return 1.0
    d = min(distances)
    return float(np.exp(-0.5 * (max(0.0, d - OOD_FREE_Z) / OOD_WIDTH) ** 2))


def _rms_z(stats: dict, f: np.ndarray, keep: np.ndarray) -> float | None:
    """RMS z-score of summary `f` over the `keep` channels against one set of statistics (None if unusable)."""
    try:
        mu = np.asarray(stats["mean"], np.float64)
        sd = np.maximum(np.asarray(stats["std"], np.float64), 1e-3)
    except (TypeError, KeyError, ValueError):
        return None
    if mu.shape != f.shape or sd.shape != f.shape:
        return None
    return float(np.sqrt(np.mean(((f - mu) / sd)[keep] ** 2)))


def voxel_confidence(logits, occupied):
    """(B,N,N,N) probability of the chosen class among the material classes (softmax without background)."""
    import torch

    p = torch.softmax(logits.float()[:, :BACKGROUND], dim=1)
    return torch.where(occupied, p.max(dim=1).values, torch.zeros_like(p[:, 0]))


def model_inputs(loaded: LoadedModel, values, channel_names: list[str]):
    """The network's input (B, C_in, …) from full grid tensors `values` (a copy: `values` stays as given),
    with the channels it never saw varying (`untrained_channels`) held at zero, as in its training."""
    x = select_inputs(values, channel_names, loaded.config.input_channels)
    untrained = set(untrained_channels(loaded.meta))
    held = [i for i, name in enumerate(loaded.config.input_channels) if name in untrained]
    if held:
        x[:, held] = 0
    return x


def _forward(loaded: LoadedModel, values, channel_names: list[str]):
    """Raw (logits, physical clamped to the label ranges) of full grid tensors."""
    import torch

    from .infer import fast_forward, fast_path_applies

    x = model_inputs(loaded, values, channel_names)
    with torch.inference_mode():
        if x.device.type == "cuda":
            with torch.autocast("cuda", dtype=torch.bfloat16):
                logits, physical = loaded.model(x)
        elif fast_path_applies(loaded.model, x):  # the same function with less work (model/infer.py)
            logits, physical = fast_forward(loaded.model, x)
        else:  # contiguous (NCDHW): the channels-last GroupNorm's float32 E[x²]−E[x]² cancels on mostly
            # empty grids (~1e-2 off in the logits on real captures, classes flipped at near-ties)
            logits, physical = loaded.model(x.contiguous())
    lo, hi = normalised_bounds(loaded.meta)
    shape = (1, 3) + (1,) * (physical.dim() - 2)
    lo_t = torch.as_tensor(lo, device=physical.device).view(shape)
    hi_t = torch.as_tensor(hi, device=physical.device).view(shape)
    return logits.float(), torch.maximum(torch.minimum(physical.float(), hi_t), lo_t)


def run_model(loaded: LoadedModel, values, channel_names: list[str], occupied):
    """(classes (B,N,N,N) long, physical (B,3,N,N,N) float32) from full grid tensors on the model's device.

    The physical outputs are clamped to the checkpoint's label ranges (`label_ranges`), so E, ν, ρ never
    leave the values the network was trained on (a raw head can extrapolate to E above diamond's)."""
    logits, physical = _forward(loaded, values, channel_names)
    return classes_from_logits(logits, occupied), physical


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
    logits, physical = _forward(loaded, values, grid.channels)
    classes = classes_from_logits(logits, occupied)
    ind = in_distribution_score(loaded.meta, object_feature_summary(values, occupied)[0].cpu().numpy())
    conf = voxel_confidence(logits, occupied)[0].cpu().numpy() * np.float32(ind)
    return MaterialGrid(classes=classes[0].cpu().numpy(), physical=physical[0].cpu().numpy(),
                        occupancy=grid.occupancy, grid=grid, confidence=conf.astype(np.float32),
                        in_distribution=ind)
