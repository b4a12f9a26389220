"""The material network: per-voxel feature projector + 3D U-Net with a class head and a physics head.

Shape follows the Pixie paper's appendix (DESIGN.md "The model"): projector 3 × (Conv3d, GroupNorm,
SiLU); U-Net with residual blocks x + f(x), f = norm → LeakyReLU(0.02) → Conv3d(3) → norm → act →
dropout → zero-initialised Conv3d(3); stride-2 conv down, nearest-upsample + conv up, skip
connections. For CPU speed the up-conv runs before the upsample and skips are added, not
concatenated. The projector uses 1×1×1 convolutions (a per-voxel MLP; the U-Net supplies the
spatial context), and width/depth are configurable so the shipped network fits CPU inference.
Optional (`context_width` > 0): an object-context branch at the bottleneck (`ObjectContext`).
Outputs: 8 class logits (ids 0–6 and 7 = background) and 3 normalised values
(log10 E, ν, log10 ρ mapped to [-1, 1] by `pixie_gs.materials.normalize_physical`).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import torch
from torch import nn

from ..materials import NUM_CLASSES


@dataclass
class ModelConfig:
    """Everything needed to rebuild the network (stored in checkpoints as a plain dict)."""

    input_channels: list[str]  # grid channel names fed to the network, in order
    projector_hidden: int = 32
    projector_out: int = 16
    base_channels: int = 16
    multipliers: list[int] = field(default_factory=lambda: [1, 2, 4])
    res_blocks: int = 1
    dropout: float = 0.0
    context_width: int = 0  # hidden width of the object-context branch at the bottleneck (0: none)
    num_classes: int = NUM_CLASSES
    num_physical: int = 3

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(**known)


def _groups(channels: int) -> int:
    return math.gcd(channels, 8)


class ResBlock(nn.Module):
    """x + f(x) (with a 1×1×1 projection of x when the width changes); the last conv starts at zero."""

    def __init__(self, cin: int, cout: int, dropout: float) -> None:
        super().__init__()
        self.f = nn.Sequential(
            nn.GroupNorm(_groups(cin), cin), nn.LeakyReLU(0.02), nn.Conv3d(cin, cout, 3, padding=1),
            nn.GroupNorm(_groups(cout), cout), nn.LeakyReLU(0.02), nn.Dropout3d(dropout),
            nn.Conv3d(cout, cout, 3, padding=1),
        )
        nn.init.zeros_(self.f[-1].weight)
        nn.init.zeros_(self.f[-1].bias)
        self.skip = nn.Identity() if cin == cout else nn.Conv3d(cin, cout, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.skip(x) + self.f(x)


class ObjectContext(nn.Module):
    """h + MLP(mean and max of h over the whole grid), broadcast to every voxel.

    The U-Net's convolutions see a neighbourhood; which object a voxel belongs to (a cushion or a ball, a
    book or a box) is a property of the whole shape. This branch gives every voxel a summary of the whole
    grid. Its last layer starts at zero, so a network grown from a checkpoint without it computes exactly
    what that checkpoint did until training moves it (`pixie train --init OLD --context-width W`).
    """

    def __init__(self, channels: int, hidden: int) -> None:
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(2 * channels, hidden), nn.SiLU(), nn.Linear(hidden, channels))
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        pooled = torch.cat([h.mean(dim=(2, 3, 4)), h.amax(dim=(2, 3, 4))], dim=1)
        return h + self.mlp(pooled)[:, :, None, None, None].to(h.dtype)


# The network's top-level parts, input to output. ENCODER_PARTS read the grid down to the bottleneck (and the
# object-context branch there); a fine-tune that freezes them (`pixie train --freeze encoder`) can change only
# how features are decoded into materials, not which features a splat yields.
ENCODER_PARTS = ("projector", "stem", "down_blocks", "downsamples", "middle", "context")
DECODER_PARTS = ("upsamples", "up_blocks", "out_norm", "class_head", "physical_head")


class MaterialUNet(nn.Module):
    """(B, C_in, N, N, N) feature grid → (logits (B, 8, N³…), physical (B, 3, N³…)); N divisible by 2^(levels−1)."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        c_in, hid, c_proj = len(config.input_channels), config.projector_hidden, config.projector_out
        self.projector = nn.Sequential(
            nn.Conv3d(c_in, hid, 1), nn.GroupNorm(_groups(hid), hid), nn.SiLU(),
            nn.Conv3d(hid, hid, 1), nn.GroupNorm(_groups(hid), hid), nn.SiLU(),
            nn.Conv3d(hid, c_proj, 1), nn.GroupNorm(_groups(c_proj), c_proj), nn.SiLU(),
        )
        widths = [config.base_channels * m for m in config.multipliers]
        self.stem = nn.Conv3d(c_proj, widths[0], 3, padding=1)
        self.down_blocks = nn.ModuleList()
        self.downsamples = nn.ModuleList()
        prev = widths[0]
        for level, w in enumerate(widths):
            blocks = []
            for _ in range(config.res_blocks):
                blocks.append(ResBlock(prev, w, config.dropout))
                prev = w
            self.down_blocks.append(nn.Sequential(*blocks))
            if level < len(widths) - 1:
                self.downsamples.append(nn.Conv3d(w, w, 3, stride=2, padding=1))
        self.middle = ResBlock(prev, prev, config.dropout)
        self.context = ObjectContext(prev, config.context_width) if config.context_width > 0 else None
        self.upsamples = nn.ModuleList()
        self.up_blocks = nn.ModuleList()
        for level in reversed(range(len(widths) - 1)):
            w = widths[level]
            # conv at the coarse level, then nearest upsample (8× cheaper than conv after it)
            self.upsamples.append(nn.Conv3d(prev, w, 3, padding=1))
            self.up_blocks.append(nn.Sequential(*[ResBlock(w, w, config.dropout) for _ in range(config.res_blocks)]))
            prev = w
        self.out_norm = nn.Sequential(nn.GroupNorm(_groups(prev), prev), nn.LeakyReLU(0.02))
        self.class_head = nn.Conv3d(prev, config.num_classes, 1)
        self.physical_head = nn.Conv3d(prev, config.num_physical, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.stem(self.projector(x))
        skips = []
        for level, blocks in enumerate(self.down_blocks):
            h = blocks(h)
            if level < len(self.downsamples):
                skips.append(h)
                h = self.downsamples[level](h)
        h = self.middle(h)
        if self.context is not None:
            h = self.context(h)
        for up, blocks in zip(self.upsamples, self.up_blocks):
            h = nn.functional.interpolate(up(h), scale_factor=2, mode="nearest")
            h = blocks(h + skips.pop())  # additive skip: same information, half the convolution cost
        h = self.out_norm(h)
        return self.class_head(h), self.physical_head(h)


def masked_loss(logits: torch.Tensor, physical: torch.Tensor, target_class: torch.Tensor,
                target_physical: torch.Tensor, occupied: torch.Tensor, class_weight: float = 1.0,
                voxel_weight: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """λ·CE + MSE(log E) + MSE(ν) + MSE(log ρ), averaged over occupied voxels only.

    logits (B,8,N,N,N), physical (B,3,…), target_class (B,N,N,N) long, target_physical (B,3,…),
    occupied (B,N,N,N) bool; voxel_weight (B,N,N,N), optional, weighs each occupied voxel's terms
    (part_balance.part_balance_weights: they sum to the occupied count, so the scale stays a mean).
    Returns (loss, parts as floats).
    """
    occ = occupied.reshape(-1)
    count = occ.sum().clamp_min(1)
    lg = logits.permute(0, 2, 3, 4, 1).reshape(-1, logits.shape[1])[occ].float()
    diff = (physical.float() - target_physical.float()).permute(0, 2, 3, 4, 1).reshape(-1, 3)[occ]
    if voxel_weight is None:
        ce = nn.functional.cross_entropy(lg, target_class.reshape(-1)[occ], reduction="sum") / count
        mse = (diff ** 2).sum(dim=0) / count
    else:
        w = voxel_weight.reshape(-1)[occ].float()
        ce = (w * nn.functional.cross_entropy(lg, target_class.reshape(-1)[occ], reduction="none")).sum() / count
        mse = (w[:, None] * diff ** 2).sum(dim=0) / count
    loss = class_weight * ce + mse.sum()
    parts = mse.detach().cpu().tolist()
    return loss, {"ce": float(ce.detach()), "mse_log_E": parts[0], "mse_nu": parts[1], "mse_log_rho": parts[2]}
