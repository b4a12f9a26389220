"""Data-parallel training over several processes (`torchrun --nproc_per_node N pixie train …`).

Each process (rank) reads what torchrun puts in its environment (RANK, WORLD_SIZE, LOCAL_RANK,
MASTER_ADDR, MASTER_PORT) and joins one process group: gloo on the CPU, nccl on CUDA with one GPU
per process (cuda:LOCAL_RANK). Sampling needs no communication: every rank draws the same shuffled
order from the shared seed and cuts it into the same global batches of `--batch-size` objects, and
rank r takes objects r, r + N, r + 2N, … of each batch (a rank-sharded sampler: the ranks' shares
are disjoint and together are the batch). Each rank's loss is then weighted by its share of the
batch's occupied voxels, so the gradient that DistributedDataParallel averages is exactly the
gradient of the one-process loss over the whole batch: same steps per epoch, same learning-rate
schedule and the same optimisation as on one device, with the work split N ways. Rank 0 alone
validates, writes checkpoints, the resume state and logs.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Mapping, Sequence

from ..errors import InputError


@dataclass(frozen=True)
class DistContext:
    """Where this process stands in the group: rank (0 … world_size − 1) and its GPU index on the host."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


SINGLE = DistContext()


def context_from_env(environ: Mapping[str, str] | None = None) -> DistContext:
    """The context torchrun describes in the environment (one process when WORLD_SIZE is unset or 1)."""
    env = os.environ if environ is None else environ
    try:
        world = int(env.get("WORLD_SIZE", "1"))
        rank = int(env.get("RANK", "0"))
        local = int(env.get("LOCAL_RANK", str(rank)))
    except ValueError:
        raise InputError("WORLD_SIZE, RANK and LOCAL_RANK must be integers (as torchrun sets them)") from None
    if world < 1 or not 0 <= rank < world or local < 0:
        raise InputError(f"inconsistent torchrun environment: RANK={rank}, WORLD_SIZE={world}, LOCAL_RANK={local}")
    return DistContext(rank, world, local)


def join(ctx: DistContext, device: str) -> str:
    """Join the process group of `ctx` (a no-op for one process); returns this rank's torch device:
    'cuda:LOCAL_RANK' (nccl) when `device` is CUDA, else 'cpu' (gloo)."""
    if not ctx.enabled:
        return device
    import torch
    import torch.distributed as dist

    if device.startswith("cuda"):
        if ctx.local_rank >= torch.cuda.device_count():
            raise InputError(f"rank {ctx.rank} wants GPU {ctx.local_rank}, but torch sees "
                             f"{torch.cuda.device_count()} (use --nproc_per_node ≤ the GPU count)")
        device, backend = f"cuda:{ctx.local_rank}", "nccl"
        torch.cuda.set_device(device)
    else:
        device, backend = "cpu", "gloo"
    if not dist.is_initialized():
        kwargs = {"device_id": torch.device(device)} if backend == "nccl" else {}
        dist.init_process_group(backend, rank=ctx.rank, world_size=ctx.world_size, **kwargs)
    return device


def leave(ctx: DistContext) -> None:
    """Leave the process group (after a barrier, so no rank exits while another still talks to it)."""
    if not ctx.enabled:
        return
    import torch.distributed as dist

    if dist.is_initialized():
        dist.destroy_process_group()


def barrier(ctx: DistContext) -> None:
    if ctx.enabled:
        import torch.distributed as dist

        dist.barrier()


def rank_share(ids: Sequence[int], ctx: DistContext) -> tuple[list[int], bool]:
    """This rank's objects of global batch `ids` (every world_size-th, from its rank) and whether they
    count. A rank left empty by a short last batch takes `ids[:1]` with counts=False: it joins the
    gradient all-reduce with weight 0, so every rank runs every step."""
    share = list(ids[ctx.rank::ctx.world_size])
    if share:
        return share, True
    return list(ids[:1]), False


def sum_across(values: Sequence[float], ctx: DistContext, device: str) -> list[float]:
    """Element-wise sum of `values` over every rank (float64; the values themselves for one process)."""
    if not ctx.enabled:
        return [float(v) for v in values]
    import torch
    import torch.distributed as dist

    t = torch.tensor([float(v) for v in values], dtype=torch.float64, device=device)
    dist.all_reduce(t)
    return t.tolist()


def from_main(values: Sequence[float], ctx: DistContext, device: str) -> list[float]:
    """Rank 0's `values` on every rank (so decisions that depend on a clock agree everywhere)."""
    if not ctx.enabled:
        return [float(v) for v in values]
    import torch
    import torch.distributed as dist

    t = torch.tensor([float(v) for v in values], dtype=torch.float64, device=device)
    dist.broadcast(t, src=0)
    return t.tolist()


PART_NAMES = ("ce", "mse_log_E", "mse_nu", "mse_log_rho")


def global_batch_loss(loss, parts: dict[str, float], occupied_voxels: int, counts: bool, class_weight: float,
                      ctx: DistContext, device: str):
    """(loss to back-propagate, its value over the whole global batch, parts over the whole batch).

    `loss` and `parts` are this rank's masked means over its `occupied_voxels`; the rank's loss is
    scaled by world_size · (its voxels / the batch's voxels), so DDP's gradient average equals the
    gradient of the masked mean over the whole batch."""
    mine = occupied_voxels if counts else 0
    sums = sum_across([mine] + [mine * parts[k] for k in PART_NAMES], ctx, device)
    total = max(sums[0], 1.0)
    whole = {k: v / total for k, v in zip(PART_NAMES, sums[1:])}
    value = class_weight * whole["ce"] + whole["mse_log_E"] + whole["mse_nu"] + whole["mse_log_rho"]
    return loss * (ctx.world_size * mine / total), value, whole
