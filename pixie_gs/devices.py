"""Choose the compute device for torch and Warp from one user-facing string."""
from __future__ import annotations

import sys

from .errors import InputError

DEVICE_CHOICES = ("auto", "cpu", "cuda")
DEVICE_HELP = "where to compute: cpu, cuda, or auto (cuda when a GPU is present; default)"
_warp_ready = False


THREAD_DEFAULTS = {"OMP_WAIT_POLICY": "PASSIVE", "OPENBLAS_NUM_THREADS": "1"}


def thread_defaults() -> None:
    """The `pixie` command's thread-pool settings (THREAD_DEFAULTS), unless the user set them. Call
    before numpy and torch are imported: their libraries read these once, when they load.

    - OMP_WAIT_POLICY=PASSIVE: torch runs each CPU operation on one OpenMP thread per core, and by
      default a thread that finishes its share spins until the others catch up. On a machine whose
      cores also run other work the spinning thread takes the time slice its partner needs: the
      U-Net of `pixie annotate` took 1.75 CPU s with two spinning threads at load average 3.6 on
      2 cores, 0.38 s passive (the same as one thread); with idle cores both still run in parallel.
    - OPENBLAS_NUM_THREADS=1: numpy's and scipy's OpenBLAS on one thread. pixie's numpy matrix
      products are small (the feature field's (G,10)@(10,K) distances, preparation's 3×3 fits), so a
      second thread gains nothing on an idle machine and, spinning the same way, costs a lot on a busy
      one (the field 0.36 → 0.16 CPU s at load average 4.8). torch's own CPU work (MKL, oneDNN) is
      not affected."""
    import os

    for name, value in THREAD_DEFAULTS.items():
        os.environ.setdefault(name, value)


def import_torch():
    """`import torch` with Python's cyclic garbage collector paused while torch loads.

    The import creates ~150k objects that live as long as the process; the collections their
    allocations trigger (three full ones) cost ~0.12 CPU s of the import's ~1 s and free little."""
    import gc
    import sys

    if "torch" in sys.modules:
        return sys.modules["torch"]
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        import torch
    finally:
        if was_enabled:
            gc.enable()
    return torch


def resolve_torch_device(name: str = "auto") -> str:
    """'auto' → 'cuda' when torch sees a GPU, else 'cpu'; 'cuda' without a GPU is an error."""
    torch = import_torch()

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError("--device cuda asked for, but torch sees no CUDA GPU on this machine")
    if name not in DEVICE_CHOICES and not name.startswith("cuda:"):
        raise InputError(f"unknown device '{name}' (choose from {', '.join(DEVICE_CHOICES)})")
    return name


def init_warp_quietly() -> None:
    """Initialise Warp without its banner and without the native 'no CUDA driver' warning that it
    prints on CPU-only machines (stderr is silenced at file-descriptor level for the init only)."""
    import logging
    import os

    import warp as wp

    global _warp_ready
    if _warp_ready:
        return
    wp.config.log_level = logging.ERROR
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 2)
            wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    _warp_ready = True


def resolve_warp_device(name: str = "auto") -> str:
    """The Warp device string for `name` ('auto' picks CUDA when Warp finds a GPU)."""
    import warp as wp

    init_warp_quietly()
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
