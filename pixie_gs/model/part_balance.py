"""Per-voxel loss weights that let an object's small parts count as much as its large ones.

The training loss averages over occupied voxels, so a part with few voxels (a broad-leaved plant's stems,
a tree's trunk, a mug's handle) adds little to it, and in a mix of kinds the network learns to read such an
object as one material (docs/model_card.md, "Stop 47"). Here each object's occupied voxels are grouped into
parts by their labels — the material class and the decade of the target E — and each voxel gets the weight
(n_object / (G_object · n_part))^α, renormalised so that every object's weights still sum to its voxel count.
α = 0 is the plain mean (every weight 1); α = 1 gives each part of an object the same total weight. Objects
keep their share of the batch, and the sum of all weights stays the occupied count, so the distributed
loss's scaling by voxel counts (distributed.global_batch_loss) still holds.
"""
from __future__ import annotations

from ..materials import LOG10_E_RANGE

E_DECADES = LOG10_E_RANGE[1] - LOG10_E_RANGE[0]  # decades spanned by the normalised log E in [-1, 1]


def label_parts(target_class, target_log_e_unit, occupied, classes: int):
    """One integer per voxel naming its (object, class, E decade) part; -1 where not occupied.

    target_class (B,N,N,N) long, target_log_e_unit (B,N,N,N) the normalised log10 E in [-1, 1],
    occupied (B,N,N,N) bool."""
    import torch

    decades = int(E_DECADES) + 1
    decade = ((target_log_e_unit.float() + 1.0) * 0.5 * E_DECADES).floor().clamp(0, decades - 1).long()
    batch = torch.arange(target_class.shape[0], device=target_class.device).view(-1, 1, 1, 1)
    key = (batch * classes + target_class.clamp(0, classes - 1)) * decades + decade
    return torch.where(occupied, key, torch.full_like(key, -1))


def part_balance_weights(target_class, target_physical, occupied, alpha: float, classes: int):
    """(B,N,N,N) float weights: 0 off the occupied voxels; on them (n_obj / (G_obj · n_part))^α scaled so
    each object's weights sum to n_obj (its occupied voxel count). α in [0, 1]; α = 0 gives all ones."""
    import torch

    weights = occupied.float()
    if alpha <= 0:
        return weights
    key = label_parts(target_class, target_physical[:, 0], occupied, classes)
    occ = occupied.reshape(-1)
    keys = key.reshape(-1)[occ]
    parts, part_of_voxel, part_size = torch.unique(keys, return_inverse=True, return_counts=True)
    obj_of_part = torch.div(parts, classes * (int(E_DECADES) + 1), rounding_mode="floor")
    n_obj = torch.bincount(obj_of_part, weights=part_size.float(), minlength=occupied.shape[0])
    g_obj = torch.bincount(obj_of_part, minlength=occupied.shape[0]).float()
    raw = (n_obj[obj_of_part] / (g_obj[obj_of_part] * part_size.float())) ** alpha  # per part, per voxel
    obj_of_voxel = obj_of_part[part_of_voxel]
    raw_voxel = raw[part_of_voxel]
    obj_sum = torch.bincount(obj_of_voxel, weights=raw_voxel, minlength=occupied.shape[0])
    flat = torch.zeros_like(weights.reshape(-1))
    flat[occ] = raw_voxel * (n_obj[obj_of_voxel] / obj_sum[obj_of_voxel])
    return flat.view_as(weights)
