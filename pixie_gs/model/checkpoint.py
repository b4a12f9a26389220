"""Checkpoints: state_dict + network config + normalisation ranges + feature-channel spec.

Saved with `torch.save` as plain dicts/lists/numbers/tensors, so `torch.load(..., weights_only=True)`
reads them on any device (tensors are mapped to CPU). The optimiser state for `--resume` lives in a
sidecar file `<checkpoint>.state.pt`, so the shipped checkpoint carries weights only.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..atomic import atomic_path
from ..errors import InputError
from ..materials import LOG10_DENSITY_RANGE, LOG10_E_RANGE, NU_RANGE
from .unet import MaterialUNet, ModelConfig

FORMAT = "pixie-gs/material-unet"
FORMAT_VERSION = 1
DEFAULT_CHECKPOINT = Path(__file__).resolve().parent.parent / "data" / "checkpoints" / "pixie_default.pt"


def normalization_ranges() -> dict[str, list[float]]:
    """The fixed (min, max) ranges the physical targets are normalised with (materials.py)."""
    return {"log10_E_pa": list(LOG10_E_RANGE), "nu": list(NU_RANGE), "log10_density_kg_m3": list(LOG10_DENSITY_RANGE)}


@dataclass
class FeatureSpec:
    """How the input grid was built: grid size, pre-filter, margin and the extra float channels."""

    resolution: int = 64
    filter_voxels: float = 0.5
    margin: float = 0.05
    extra_names: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return {"resolution": self.resolution, "filter_voxels": self.filter_voxels, "margin": self.margin,
                "extra_names": list(self.extra_names)}

    @classmethod
    def from_dict(cls, d: dict) -> "FeatureSpec":
        return cls(int(d["resolution"]), float(d["filter_voxels"]), float(d["margin"]), tuple(d["extra_names"]))


@dataclass
class LoadedModel:
    """A network ready for inference plus what it needs to build its input."""

    model: MaterialUNet
    config: ModelConfig
    features: FeatureSpec
    meta: dict
    path: str


def save_checkpoint(path: str | Path, model: MaterialUNet, features: FeatureSpec, meta: dict | None = None) -> None:
    """Write the checkpoint atomically (weights on CPU, config and specs as plain data)."""
    import torch

    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "config": model.config.to_dict(),
        "features": features.to_dict(),
        "normalization": normalization_ranges(),
        "state_dict": {k: v.detach().to("cpu", dtype=torch.float32 if v.is_floating_point() else v.dtype)
                       for k, v in model.state_dict().items()},
        "meta": meta or {},
    }
    with atomic_path(path, suffix=".pt.tmp") as tmp:
        torch.save(payload, tmp)


def load_checkpoint(path: str | Path | None = None, device: str = "cpu") -> LoadedModel:
    """Load a checkpoint (the shipped default when `path` is None) onto `device`, in eval mode."""
    import torch

    path = Path(path) if path is not None else DEFAULT_CHECKPOINT
    if not path.is_file():
        raise InputError("checkpoint not found" + (" (the shipped default is missing from this install)"
                                                    if path == DEFAULT_CHECKPOINT else ""), path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for foreign or damaged files
        raise InputError(f"not a readable torch checkpoint ({str(exc).splitlines()[0][:120]})", path) from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise InputError(f"not a pixie-gs material checkpoint (format must be '{FORMAT}')", path)
    if payload.get("normalization") != normalization_ranges():
        raise InputError("checkpoint uses different (E, nu, density) normalisation ranges than this pixie-gs", path)
    config = ModelConfig.from_dict(payload["config"])
    model = MaterialUNet(config)
    try:
        model.load_state_dict(payload["state_dict"])
    except RuntimeError as exc:
        raise InputError(f"weights do not match the stored config ({str(exc).splitlines()[0][:120]})", path) from None
    model.to(device).eval()
    if device == "cpu":  # channels-last 3D convolutions are ~15 % faster with oneDNN on CPU
        model.to(memory_format=torch.channels_last_3d)
    return LoadedModel(model, config, FeatureSpec.from_dict(payload["features"]), dict(payload.get("meta", {})), str(path))


def state_path(checkpoint: str | Path) -> Path:
    """Sidecar file holding the optimiser/epoch state for `pixie train --resume`."""
    return Path(str(checkpoint) + ".state.pt")
