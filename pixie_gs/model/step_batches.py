"""The training steps' batches, with the grids of several consecutive steps built in one pass.

Building a batch (batch.py: augmentation, `prepare_gaussians`, `splat_field`, labels) costs time per
object and a fixed time per call: the field's stencil groups (one per reach and octant, ~130 for a
typical object) each launch their own kernels and host syncs on CUDA, whatever the number of objects.
Measured on an H200 (docs/training.md), that fixed part made a step of 16 objects cost far more than half
a step of 32, so two GPUs could not reach twice the throughput of one. Building `objects_per_build`
objects per call (several steps' worth) and slicing them per step pays the fixed part once for all of
them. The objects, their order and their augmentation draws are those of per-step building (the draws
come from the same generator in the same order), and each object's grid does not depend on its
neighbours in a call, so the batches are the same.
"""
from __future__ import annotations

import math
from typing import Iterator

from .batch import AugmentConfig, Batch, build_batch
from .checkpoint import FeatureSpec
from .distributed import SINGLE, DistContext, rank_share

CUDA_OBJECTS_PER_BUILD = 128  # at most this many objects per build call on CUDA
BUILD_MEMORY_SHARE = 0.15  # of the GPU memory free before training, per call (two calls are alive at a time)


def default_objects_per_build(device: str, resolution: int, channels: int) -> int:
    """Objects per build call: on CUDA as many as fit in BUILD_MEMORY_SHARE of the free memory (at most
    CUDA_OBJECTS_PER_BUILD; a 64³ grid with ~20 channels needs ~60 MB per object); on the CPU one step's
    (the numpy field has no launch or sync cost per group, and the memory stays one step's)."""
    if not str(device).startswith("cuda"):
        return 1
    import torch

    free, _ = torch.cuda.mem_get_info(torch.device(device))
    padded = (resolution + 14) ** 3  # the field's padded grid (max_radius_voxels 6)
    per_object = 4 * (padded * (channels + 1) + resolution ** 3 * (channels + 6))  # bytes, float32
    return int(max(1, min(CUDA_OBJECTS_PER_BUILD, BUILD_MEMORY_SHARE * free // per_object)))


def slice_batch(batch: Batch, start: int, stop: int) -> Batch:
    """Objects start … stop − 1 of a built batch (views along the batch dimension)."""
    return Batch(batch.inputs[start:stop], batch.occupied[start:stop], batch.target_class[start:stop],
                 batch.target_physical[start:stop], batch.means_unit[start:stop])


def step_batches(store, batches: list[list[int]], spec: FeatureSpec, augment: AugmentConfig | None, epoch_seed: int,
                 ctx: DistContext = SINGLE, objects_per_build: int = 1) -> Iterator[tuple[list[int], Batch, bool]]:
    """For each global batch of `batches`: (its ids, this rank's share built as a Batch, whether the share
    counts — see `rank_share`). Consecutive steps are built together, about `objects_per_build` of this
    rank's objects per call."""
    if not batches:
        return
    per_step = max(1, math.ceil(max(len(b) for b in batches) / ctx.world_size))
    group = max(1, objects_per_build // per_step)
    for g0 in range(0, len(batches), group):
        chunk = batches[g0:g0 + group]
        shares = [rank_share(ids, ctx) for ids in chunk]
        built = build_batch(store, [i for share, _ in shares for i in share], spec, augment, epoch_seed)
        start = 0
        for ids, (share, counts) in zip(chunk, shares):
            yield ids, slice_batch(built, start, start + len(share)), counts
            start += len(share)
