"""Training/evaluation batches: (augmented) Gaussians → input grids and voxel labels, on the device.

Inputs go through exactly the code `pixie annotate` uses (`prepare_gaussians` + `splat_field` +
`grid_channels`). Voxel labels come from the same weights w_i(x) = α_i G_i(x): the class is the
weighted vote of the Gaussians' material ids, the targets their weighted mean normalised
(log10 E, ν, log10 ρ). Augmentation acts on the Gaussians before normalisation: a random yaw
rotation about +z, random x/y flips, per-axis scale jitter (covariances follow: Σ' = A Σ Aᵀ),
colour jitter (per-channel gain and a brightness offset) and, when asked, a random tilt, a random
grid margin (framing), painted decals (`paint_decals`) and a hue and saturation shift (`shift_hue`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..field import GaussianTensors, grid_channels, prepare_gaussians, splat_field
from ..materials import BACKGROUND, NUM_CLASSES
from .checkpoint import FeatureSpec


@dataclass
class AugmentConfig:
    yaw: bool = True
    flips: bool = True
    scale_jitter: float = 0.15  # per-axis stretch factor in [1 − j, 1 + j]
    colour_gain: float = 0.1  # per-channel RGB gain in [1 − g, 1 + g]
    brightness: float = 0.05  # RGB offset in [−b, b]
    # A share of objects tilted about a random horizontal axis by up to this angle (degrees): generated
    # objects stand nearly upright (residual tilt ≤ 20°), so a metal can tilted 30° read as elastic.
    tilt_max_deg: float = 0.0
    tilt_share: float = 0.5
    # Framing: each object's grid margin drawn uniformly between the spec's margin and this (0: always the
    # spec's). An object may fill much less of the grid in use (a crop, a ground plane, leftover capture),
    # and accuracy falls as it does (benchmarks/bench_framing.py).
    margin_max: float = 0.0
    # Decals: this share of objects gets 2–MAX_DECALS balls of one random colour painted over its Gaussians
    # (0: none). Real objects carry labels, paint, prints and dirt; generated metal is plain, so r50 reads a
    # high-contrast metal helmet (benchmarks/real_holdout) as soft and the same helmet painted grey as metal.
    decal_share: float = 0.0
    # Hue: this share of objects has its colours turned about the grey axis by up to ±180° and its saturation
    # scaled by SATURATION_RANGE (0: none). r50 reads a photographed potted plant as wood and metal, and the
    # same plant painted leaf green as soft: the generator's palettes are narrower than the world's.
    hue_share: float = 0.0


MAX_DECALS = 8
SATURATION_RANGE = (0.3, 1.5)  # saturation scale of a hue-shifted object
DECAL_RADIUS = (0.08, 0.3)  # radius range of one decal, as a share of the object's largest extent


@dataclass
class Batch:
    """inputs (B,C,N,N,N) full grid channels, occupied (B,N,N,N), target_class (B,N,N,N) long,
    target_physical (B,3,N,N,N), and each object's unit-cube Gaussian centres (list of (M_b,3))."""

    inputs: object
    occupied: object
    target_class: object
    target_physical: object
    means_unit: list


def augmentation_matrix(gen, cfg: AugmentConfig, device):
    """A = T · S · R_yaw · F (3,3): flips, a yaw rotation about +z, a per-axis stretch, then (a share
    `tilt_share` of objects, when `tilt_max_deg` > 0) a tilt T about a random horizontal axis. Without
    tilt no further numbers are drawn, so earlier runs' augmentations are unchanged."""
    import torch

    u = torch.rand(6, generator=gen)
    theta = float(u[0]) * 2 * math.pi if cfg.yaw else 0.0
    c, s = math.cos(theta), math.sin(theta)
    rot = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    flip = torch.diag(torch.tensor([(-1.0 if float(u[1]) < 0.5 else 1.0) if cfg.flips else 1.0,
                                    (-1.0 if float(u[2]) < 0.5 else 1.0) if cfg.flips else 1.0, 1.0]))
    stretch = torch.diag(1.0 + cfg.scale_jitter * (2 * u[3:6] - 1))
    a = stretch @ rot @ flip
    if cfg.tilt_max_deg > 0:
        t = torch.rand(3, generator=gen)
        if float(t[0]) < cfg.tilt_share:
            from ..dataset.realism import horizontal_tilt  # the captures' tilt; training imports dataset anyway

            tilt = horizontal_tilt(math.radians(cfg.tilt_max_deg) * float(t[1]), 2 * math.pi * float(t[2]))
            a = torch.as_tensor(tilt, dtype=a.dtype) @ a
    return a.to(device)


def paint_decals(gen, means, rgb, share: float):
    """rgb (M,3) with, for a `share` of calls, 2–MAX_DECALS balls painted one uniform random colour each: every
    Gaussian whose centre (means (M,3)) lies within a ball takes its colour (later balls over earlier ones).
    Always draws the same count of numbers from `gen`, so what follows does not depend on the outcome."""
    import torch

    u = torch.rand(2 + 5 * MAX_DECALS, generator=gen)
    if float(u[0]) >= share or len(means) == 0:
        return rgb
    extent = float((means.max(0).values - means.min(0).values).max())
    painted = rgb.clone()
    for j in range(2 + int(float(u[1]) * (MAX_DECALS - 1))):
        d = u[2 + 5 * j: 7 + 5 * j]
        centre = means[min(int(float(d[0]) * len(means)), len(means) - 1)]
        radius = extent * (DECAL_RADIUS[0] + (DECAL_RADIUS[1] - DECAL_RADIUS[0]) * float(d[1]))
        inside = ((means - centre) ** 2).sum(1) <= radius * radius
        painted[inside] = d[2:5].to(painted.device, painted.dtype)
    return painted


def turn_hue(rgb, angle_rad: float, saturation: float):
    """rgb (M,3) turned about the grey axis (1,1,1) by `angle_rad` (the mean of the channels kept; 120° maps
    red to green) and its distance from grey scaled by `saturation`, clamped to [0, 1]."""
    import torch

    eye = torch.eye(3, dtype=rgb.dtype, device=rgb.device)
    k = torch.full((3,), 1 / math.sqrt(3), dtype=rgb.dtype, device=rgb.device)
    cross = torch.tensor([[0.0, -1.0, 1.0], [1.0, 0.0, -1.0], [-1.0, 1.0, 0.0]], dtype=rgb.dtype,
                         device=rgb.device) / math.sqrt(3)  # K with K v = k × v
    turn = math.cos(angle_rad) * eye + math.sin(angle_rad) * cross + (1 - math.cos(angle_rad)) * torch.outer(k, k)
    grey = rgb.mean(1, keepdim=True)
    return (grey + saturation * ((rgb @ turn.T) - grey)).clamp(0.0, 1.0)


def shift_hue(gen, rgb, share: float):
    """rgb (M,3) in [0, 1], for a `share` of calls turned by one angle drawn in [−180°, 180°] with one
    saturation factor drawn in SATURATION_RANGE (`turn_hue`). Always draws 3 numbers from `gen`."""
    import torch

    u = torch.rand(3, generator=gen)
    if float(u[0]) >= share:
        return rgb
    saturation = SATURATION_RANGE[0] + (SATURATION_RANGE[1] - SATURATION_RANGE[0]) * float(u[2])
    return turn_hue(rgb, math.pi * (2 * float(u[1]) - 1), saturation)


def object_generator(epoch_seed: int, index: int):
    """The random draws that augment object `index` of the store in one epoch (`epoch_seed`): the same
    whichever process builds it, so training on N processes sees the same augmented objects as on one
    (with the shared shuffling, the same run up to float summation order)."""
    import torch

    return torch.Generator().manual_seed((int(epoch_seed) * 1_000_003 + int(index)) % (2 ** 63))


def build_batch(store, ids: list[int], spec: FeatureSpec, augment: AugmentConfig | None = None,
                epoch_seed: int = 0) -> Batch:
    """Grids and labels for objects `ids` of a DeviceStore (augmented when `augment` is given, each object
    by its own draws: `object_generator(epoch_seed, id)`)."""
    import torch

    dev = store.device
    n = spec.resolution
    mus, covs, alphas, feats, bidx, means_unit = [], [], [], [], [], []
    for b, i in enumerate(ids):
        o = store.object(i)
        means, cov, rgb = o["means"], o["covariances"], o["rgb"]
        if augment is not None:
            gen = object_generator(epoch_seed, i)
            a = augmentation_matrix(gen, augment, dev)
            means = means @ a.T
            cov = a @ cov @ a.T
            g = torch.rand(4, generator=gen).to(dev)
            gain = 1.0 + augment.colour_gain * (2 * g[:3] - 1)
            rgb = (rgb * gain + augment.brightness * (2 * g[3] - 1)).clamp(0.0, 1.0)
        margin = spec.margin
        if augment is not None and augment.margin_max > spec.margin:  # drawn last: earlier draws unchanged
            margin += (augment.margin_max - spec.margin) * float(torch.rand(1, generator=gen))
        if augment is not None and augment.decal_share > 0:  # drawn after everything else: earlier draws unchanged
            rgb = paint_decals(gen, means, rgb, augment.decal_share)
        if augment is not None and augment.hue_share > 0:  # drawn last of all
            rgb = shift_hue(gen, rgb, augment.hue_share)
        mu, cv, al, ft, _, _ = prepare_gaussians(
            GaussianTensors(means, cov, o["alphas"], rgb, o["sh_energy"], o["extras"]), margin)
        labels = torch.cat([torch.nn.functional.one_hot(o["material_id"], NUM_CLASSES).float(), o["physical"]], 1)
        mus.append(mu)
        covs.append(cv)
        alphas.append(al)
        feats.append(torch.cat([ft, labels], dim=1))
        bidx.append(torch.full((len(mu),), b, dtype=torch.long, device=dev))
        means_unit.append(mu)
    feats_all = torch.cat(feats)
    dens, sums = splat_field(torch.cat(mus), torch.cat(covs), torch.cat(alphas), feats_all, n,
                             filter_voxels=spec.filter_voxels, batch_index=torch.cat(bidx), batch_size=len(ids))
    n_in = feats_all.shape[1] - NUM_CLASSES - 3
    inputs, occ = grid_channels(dens, sums[..., :n_in], n)
    votes = sums[..., n_in:n_in + NUM_CLASSES]
    target_class = torch.where(occ.view(len(ids), -1), votes.argmax(-1), torch.full_like(votes[..., 0], BACKGROUND).long())
    phys = sums[..., n_in + NUM_CLASSES:] / dens.clamp_min(1e-8)[..., None]
    phys = torch.where(occ.view(len(ids), -1, 1), phys, torch.zeros_like(phys))
    b = len(ids)
    return Batch(inputs, occ, target_class.view(b, n, n, n),
                 phys.view(b, n, n, n, 3).permute(0, 4, 1, 2, 3).contiguous(), means_unit)
