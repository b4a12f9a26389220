"""Distillation toward a teacher checkpoint during a fine-tune (`pixie train --distill CKPT`).

Why: every fine-tune that taught new kinds moved the old kinds' readings too — on generated objects
(ceramic vases' log E MSE 0.000 → 0.095) and on real captures (the development set's redplant is lost
after one epoch; docs/model_card.md, "Candidates r62 and r63"). Weight averaging with the old checkpoint
unlearns the new kinds, and an L2-SP anchor on the weights held r45 so close that it learned nothing. This
term holds the *outputs* instead: on the objects of kinds the teacher knew, the student is pulled towards
the teacher's class distribution and E, ν, ρ on the same augmented grid, while the labels alone teach the
kinds listed in `--distill-skip` (the teacher never saw them, so its outputs there are no guide).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple, Sequence

from ..errors import InputError

if TYPE_CHECKING:
    import torch

    from .checkpoint import FeatureSpec, LoadedModel
    from .unet import MaterialUNet


class Distillation(NamedTuple):
    """What one training step needs to add the term: the teacher, which objects of this rank's batch take
    part, and the term's weight."""

    teacher: "MaterialUNet"
    keep: "torch.Tensor"  # (B,) bool
    weight: float


def distillation_loss(logits: "torch.Tensor", physical: "torch.Tensor", teacher_logits: "torch.Tensor",
                      teacher_physical: "torch.Tensor", occupied: "torch.Tensor", keep: "torch.Tensor"
                      ) -> tuple["torch.Tensor", int]:
    """(KL(p_teacher ‖ p_student) + Σ over log E, ν, log ρ of (student − teacher)², averaged over the
    occupied voxels of the objects with keep[b] True — a 0-d tensor, 0 when no voxel is kept — and the
    number of those voxels).

    logits, teacher_logits (B,K,N,N,N); physical, teacher_physical (B,3,N,N,N) normalised targets;
    occupied (B,N,N,N) bool; keep (B,) bool."""
    import torch

    mask = (occupied & keep.view(-1, 1, 1, 1)).reshape(-1)
    count = int(mask.sum())
    if count == 0:
        return logits.sum() * 0.0, 0  # keeps the graph: every rank back-propagates the same way
    k = logits.shape[1]
    log_p = torch.log_softmax(logits.float().permute(0, 2, 3, 4, 1).reshape(-1, k)[mask], dim=1)
    log_q = torch.log_softmax(teacher_logits.float().permute(0, 2, 3, 4, 1).reshape(-1, k)[mask], dim=1)
    kl = (log_q.exp() * (log_q - log_p)).sum()
    diff = (physical.float() - teacher_physical.float()).permute(0, 2, 3, 4, 1).reshape(-1, 3)[mask]
    return (kl + (diff ** 2).sum()) / count, count


def kept_objects(class_names: Sequence[str], ids: Sequence[int], skip: Sequence[str]) -> list[bool]:
    """For each object id of a batch, whether it takes part in the distillation (its kind is not skipped).

    A pair object (`generate --pairs`) carries its first object's kind only, so its partner is distilled or
    skipped with it."""
    skipped = set(skip)
    return [class_names[i] not in skipped for i in ids]


def load_teacher(path: str, device: str) -> "LoadedModel":
    """The teacher checkpoint on `device`, its network in eval mode without gradients. Loaded before the
    training data (minutes on a large set), so a missing or broken file is named at once."""
    from .checkpoint import load_checkpoint

    teacher = load_checkpoint(path, device)
    teacher.model.eval()
    for p in teacher.model.parameters():
        p.requires_grad_(False)
    return teacher


def check_teacher_fits(teacher: "LoadedModel", input_channels: Sequence[str], spec: "FeatureSpec") -> None:
    """The teacher runs on the student's grids, so it must read the same input channels from grids built the
    same way (resolution, pre-filter, margin); raises InputError naming the teacher otherwise."""
    if list(teacher.config.input_channels) != list(input_channels):
        raise InputError("--distill checkpoint reads other input channels than the network being trained",
                         teacher.path)
    mine, theirs = spec.to_dict(), teacher.features.to_dict()
    differ = [k for k in ("resolution", "filter_voxels", "margin") if mine[k] != theirs[k]]
    if differ:
        raise InputError("--distill checkpoint was trained on other grids ("
                         + ", ".join(f"{k} {theirs[k]} against {mine[k]}" for k in differ) + ")", teacher.path)
