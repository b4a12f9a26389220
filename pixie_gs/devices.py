"""Choose the compute device for torch and Warp from one user-facing string."""
from __future__ import annotations

from .errors import InputError

DEVICE_CHOICES = ("auto", "cpu", "cuda")


def resolve_torch_device(name: str = "auto") -> str:
    """'auto' → 'cuda' when torch sees a GPU, else 'cpu'; 'cuda' without a GPU is an error."""
    import torch

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError("--device cuda asked for, but torch sees no CUDA GPU on this machine")
    if name not in DEVICE_CHOICES and not name.startswith("cuda:"):
        raise InputError(f"unknown device '{name}' (choose from {', '.join(DEVICE_CHOICES)})")
    return name


def resolve_warp_device(name: str = "auto") -> str:
    """The Warp device string for `name` ('auto' picks CUDA when Warp finds a GPU)."""
    import warp as wp

    wp.config.quiet = True
    wp.init()
    has_cuda = wp.get_cuda_device_count() > 0
    if name == "auto":
        return "cuda:0" if has_cuda else "cpu"
    if name.startswith("cuda"):
        if not has_cuda:
            raise InputError("--device cuda asked for, but Warp finds no CUDA GPU on this machine")
        return "cuda:0" if name == "cuda" else name
    if name != "cpu":
        raise InputError(f"unknown device '{name}' (choose from {', '.join(DEVICE_CHOICES)})")
    return "cpu"
