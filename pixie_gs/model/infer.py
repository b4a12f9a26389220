"""CPU inference of `MaterialUNet`: the function of `MaterialUNet.forward`, computed with less work.

Used by `pixie_gs.model.predict` for float32 CPU tensors (annotate, evaluate). Each rewrite is exact
up to float rounding; tests/test_model.py compares the result with the module and with float64.

- every convolution goes straight to oneDNN (`torch.mkldnn_convolution`), channels-last. PyTorch's
  dispatcher sends batch-1 3-D convolutions whose channels × depth × height is small (the 32³ and
  16³ levels here) to its unfold + GEMM fallback, ~10× slower: that heuristic was made for images.
- GroupNorm statistics are taken on mean-shifted values and combined in float64 (`_group_norm`):
  PyTorch's channels-last kernel computes E[x²] − E[x]² in float32, ~1e-2 off on mostly empty grids.
- the projector (1×1×1 convolutions, GroupNorm, SiLU: a per-voxel MLP) runs once per distinct
  input row: every empty-space voxel (all channels 0, ~90 % of a 64³ grid) gets the same output,
  and GroupNorm counts that row with its multiplicity.
- activations and residual additions in place, upsample + skip as one broadcast addition, and the
  two 1×1×1 heads as one convolution (fewer passes over 16–64 MB tensors, fewer page faults).
"""
from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from .unet import MaterialUNet, ResBlock


def fast_path_applies(model: MaterialUNet, x: torch.Tensor) -> bool:
    """True when `fast_forward` can run `x` through `model` (eval mode, float32 CPU, oneDNN present)."""
    return (not model.training and x.device.type == "cpu" and x.dtype == torch.float32 and x.dim() == 5
            and torch.backends.mkldnn.is_available() and hasattr(torch, "mkldnn_convolution"))


@torch.inference_mode()
def fast_forward(model: MaterialUNet, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """`model(x)` (logits, physical) for a float32 CPU batch (B, C_in, N, N, N), as inference-mode tensors.

    Samples are independent (GroupNorm is per sample), so a batch runs one sample at a time."""
    if not fast_path_applies(model, x):
        raise ValueError("fast_forward needs an eval-mode model and a float32 CPU (B, C, N, N, N) tensor")
    if len(x) != 1:
        outs = [fast_forward(model, x[b:b + 1]) for b in range(len(x))]
        return torch.cat([o[0] for o in outs]), torch.cat([o[1] for o in outs])
    h = _conv(_projector(model.projector, x), model.stem)
    skips = []
    for level, blocks in enumerate(model.down_blocks):
        h = _blocks(blocks, h)
        if level < len(model.downsamples):
            skips.append(h)
            h = _conv(h, model.downsamples[level])
    h = _res_block(model.middle, h)
    if model.context is not None:
        h = model.context(h)  # pooled over the 16³ bottleneck: cheap, so the module itself
    for up, blocks in zip(model.upsamples, model.up_blocks):
        h = _blocks(blocks, _add_upsampled(skips.pop(), _conv(h, up)))
    norm, act = model.out_norm
    h = _norm_act(h, norm, act)
    a, b = model.class_head, model.physical_head  # both 1×1×1: one pass over h
    out = torch.mkldnn_convolution(h, torch.cat([a.weight, b.weight]), torch.cat([a.bias, b.bias]),
                                   [0, 0, 0], [1, 1, 1], [1, 1, 1], 1)
    return out[:, :a.out_channels], out[:, a.out_channels:]


def _conv(x: torch.Tensor, conv: nn.Conv3d) -> torch.Tensor:
    return torch.mkldnn_convolution(x, conv.weight, conv.bias, list(conv.padding), list(conv.stride),
                                    list(conv.dilation), conv.groups)


def _norm_act(x: torch.Tensor, norm: nn.GroupNorm, act: nn.Module) -> torch.Tensor:
    """act(norm(x)), the activation in place on the normalised tensor (LeakyReLU / SiLU)."""
    h = _group_norm(x, norm)
    if isinstance(act, nn.LeakyReLU):
        return F.leaky_relu_(h, act.negative_slope)
    if isinstance(act, nn.SiLU):
        return F.silu(h, inplace=True)
    return act(h)


def _group_norm(x: torch.Tensor, norm: nn.GroupNorm) -> torch.Tensor:
    """GroupNorm of a channels-last (1, C, D, H, W) tensor with statistics as exact as float64 ones.

    PyTorch's channels-last kernel takes the variance as E[x²] − E[x]² in float32, which cancels
    when a group's mean is large next to its spread (here: most voxels are empty space, all alike):
    ~1e-2 off in the logits on real captures. Here each channel is first shifted by a value close
    to its mean (the mean of a strided sample), so the float32 sums do not cancel; the group
    statistics are then combined in float64."""
    c, g = x.shape[1], norm.num_groups
    v = x.permute(0, 2, 3, 4, 1).reshape(-1, c)  # a view: (voxels, channels)
    centre = v[:: max(1, len(v) // 4096)].mean(0)
    d = v - centre
    n = len(v)
    mean_d = d.sum(0).double() / n
    mean_sq = d.square_().sum(0).double() / n  # (torch.linalg.vector_norm sums squares less exactly)
    channel_mean = (centre.double() + mean_d).view(g, -1)
    channel_var = (mean_sq - mean_d ** 2).view(g, -1)
    mean = channel_mean.mean(1, keepdim=True)
    var = (channel_var + (channel_mean - mean) ** 2).mean(1, keepdim=True)
    scale = torch.rsqrt(var + norm.eps) * norm.weight.double().view(g, -1)
    shift = norm.bias.double().view(g, -1) - mean * scale
    view = (1, c) + (1,) * (x.dim() - 2)
    return torch.addcmul(shift.float().view(view), x, scale.float().view(view))


def _res_block(block: ResBlock, x: torch.Tensor) -> torch.Tensor:
    """skip(x) + f(x) with f = norm → act → conv → norm → act → (dropout: identity in eval) → conv."""
    n1, a1, c1, n2, a2, _dropout, c2 = block.f
    h = _conv(_norm_act(x, n1, a1), c1)
    h = _conv(_norm_act(h, n2, a2), c2)
    return h.add_(x if isinstance(block.skip, nn.Identity) else _conv(x, block.skip))


def _blocks(blocks: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    for block in blocks:
        x = _res_block(block, x)
    return x


def _add_upsampled(skip: torch.Tensor, coarse: torch.Tensor) -> torch.Tensor:
    """skip + nearest-2× upsample(coarse), written into `skip` (used once) without the upsampled copy."""
    b, c, d, h, w = coarse.shape
    if skip.shape != (b, c, 2 * d, 2 * h, 2 * w):
        return skip.add_(F.interpolate(coarse, scale_factor=2, mode="nearest"))
    fine = skip.unflatten(4, (w, 2)).unflatten(3, (h, 2)).unflatten(2, (d, 2))  # (B, C, d, 2, h, 2, w, 2) view
    fine.add_(coarse[:, :, :, None, :, None, :, None])
    return skip


def _projector(projector: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """The projector's output (1, C_out, N, N, N) channels-last, computed once per distinct input row.

    Rows that are all zero share one output; GroupNorm's mean and variance are sums over the
    computed rows weighted by how many voxels each stands for."""
    c = x.shape[1]
    shape = x.shape[2:]
    n = shape.numel()
    flat = x[0].permute(1, 2, 3, 0).reshape(n, c)
    nonzero = flat.ne(0).any(1).nonzero().squeeze(1)
    rows = torch.cat([flat[nonzero], flat.new_zeros(1, c)])
    weight = torch.ones(len(rows), dtype=torch.float64)
    weight[-1] = n - len(nonzero)
    layers = list(projector)
    for i in range(0, len(layers), 3):
        conv, norm, act = layers[i:i + 3]
        rows = torch.addmm(conv.bias, rows, conv.weight.reshape(conv.out_channels, -1).t())
        rows = act(_group_norm_rows(rows, weight, n, norm))
    out = rows[-1].expand(n, rows.shape[1]).contiguous()
    out[nonzero] = rows[:-1]
    return out.view(1, *shape, rows.shape[1]).permute(0, 4, 1, 2, 3)  # channels-last 3-D layout


def _group_norm_rows(rows: torch.Tensor, weight: torch.Tensor, count: int, norm: nn.GroupNorm) -> torch.Tensor:
    """GroupNorm of a volume given as distinct rows (R, C) each standing for `weight` (R,) voxels (`count` in all)."""
    g = norm.num_groups
    r = rows.double().view(len(rows), g, -1)
    per = count * r.shape[2]
    mean = (r.sum(2) * weight[:, None]).sum(0) / per
    var = (((r - mean[None, :, None]) ** 2).sum(2) * weight[:, None]).sum(0) / per
    inv = torch.rsqrt(var + norm.eps)
    gamma = norm.weight.double().view(g, -1)
    scale = inv[:, None] * gamma
    shift = norm.bias.double().view(g, -1) - mean[:, None] * scale
    return torch.addcmul(shift.reshape(-1), r.reshape(len(rows), -1), scale.reshape(-1)).float()
