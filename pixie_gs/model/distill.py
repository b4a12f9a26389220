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

from typing import Sequence

from ..errors import InputError


def distillation_loss(logits, physical, teacher_logits, teacher_physical, occupied, keep):
    """KL(p_teacher ‖ p_student) + Σ over log E, ν, log ρ of (student − teacher)², averaged over the
    occupied voxels of the objects with keep[b] True; a 0-d tensor, and 0 when no voxel is kept.

    logits, teacher_logits (B,K,N,N,N); physical, teacher_physical (B,3,N,N,N) normalised targets;
    occupied (B,N,N,N) bool; keep (B,) bool."""
    import torch

    mask = (occupied & keep.view(-1, 1, 1, 1)).reshape(-1)
    count = mask.sum()
    if int(count) == 0:
        return logits.sum() * 0.0  # keeps the graph: every rank back-propagates the same way
    k = logits.shape[1]
    log_p = torch.log_softmax(logits.float().permute(0, 2, 3, 4, 1).reshape(-1, k)[mask], dim=1)
    log_q = torch.log_softmax(teacher_logits.float().permute(0, 2, 3, 4, 1).reshape(-1, k)[mask], dim=1)
    kl = (log_q.exp() * (log_q - log_p)).sum()
    diff = (physical.float() - teacher_physical.float()).permute(0, 2, 3, 4, 1).reshape(-1, 3)[mask]
    return (kl + (diff ** 2).sum()) / count


def kept_objects(class_names: Sequence[str], ids: Sequence[int], skip: Sequence[str]) -> list[bool]:
    """For each object id of a batch, whether it takes part in the distillation (its kind is not skipped)."""
    skipped = set(skip)
    return [class_names[i] not in skipped for i in ids]


def load_teacher(path: str, input_channels: Sequence[str], device: str):
    """The teacher network (eval mode, no gradients) on `device`; it must read the same input channels as
    the network being trained, since it runs on the same grids."""
    from .checkpoint import load_checkpoint

    teacher = load_checkpoint(path, device)
    if list(teacher.config.input_channels) != list(input_channels):
        raise InputError("--distill checkpoint reads other input channels than the network being trained", path)
    teacher.model.eval()
    for p in teacher.model.parameters():
        p.requires_grad_(False)
    return teacher.model
