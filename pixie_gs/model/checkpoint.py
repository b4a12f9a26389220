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


def read_payload(path: Path) -> dict:
    """The checkpoint file's dict as `torch.load(weights_only=True)` reads it, not yet validated; a
    missing or unreadable file is a one-line InputError naming it."""
    if not path.is_file():
        raise InputError("checkpoint not found" + (" (the shipped default is missing from this install)"
                                                    if path == DEFAULT_CHECKPOINT else ""), path)
    return load_weights_only(path, "torch checkpoint")


def load_weights_only(path: Path, what: str) -> object:
    """`torch.load(path, weights_only=True)` on the CPU, any failure a one-line InputError naming the file as
    not a readable `what`; torch's own warnings about the file (an unusual pickle protocol) are not printed, the
    error says what is wrong."""
    import pickle
    import warnings

    import torch

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        if "weights only" in str(exc).lower():  # a pickle of arbitrary Python objects: loading it could run code
            raise InputError(f"not a readable {what} (it holds Python objects other than tensors and numbers, "
                             "which are not loaded because loading them could run code)", path) from None
        raise InputError(f"not a readable {what} (damaged pickle: {_first_line(exc)})", path) from None
    except Exception as exc:  # torch raises many types for foreign or damaged files
        raise InputError(f"not a readable {what} ({_first_line(exc)})", path) from None


def _first_line(exc: BaseException) -> str:
    """The first line of an exception's text (120 characters at most), or its type's name."""
    return str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__


def load_checkpoint(path: str | Path | None = None, device: str = "cpu") -> LoadedModel:
    """Load a checkpoint (the shipped default when `path` is None) onto `device`, in eval mode."""
    path = Path(path) if path is not None else DEFAULT_CHECKPOINT
    payload = read_payload(path)
    config, features, model = _validate(payload, path)  # the model on the meta device: weights assigned below
    weights = {k: v.float() if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    try:
        model.load_state_dict(weights, assign=True)
    except RuntimeError as exc:
        text = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        raise InputError(f"weights do not match the stored config ({text})", path) from None
    model.to(device).eval()  # contiguous layout: PyTorch's channels-last GroupNorm is ~1e-2 off (predict.py)
    meta = payload.get("meta")
    return LoadedModel(model, config, features, dict(meta) if isinstance(meta, dict) else {}, str(path))


# Sane ranges of a checkpoint's numbers: a damaged or hostile payload is refused before any allocation.
RESOLUTION_RANGE = (8, 512)  # feature grid cells per side
CHANNELS_RANGE = (1, 1024)  # projector and U-Net widths
MULTIPLIER_RANGE = (1, 64)
MAX_LEVELS = 6
MAX_RES_BLOCKS = 16


def validate_payload(payload: object, path: str | Path) -> tuple[ModelConfig, FeatureSpec]:
    """Check a loaded checkpoint dict against the schema (types, ranges, sizes, finite weights,
    a memory estimate); return its (ModelConfig, FeatureSpec) or raise a one-line InputError."""
    config, features, _ = _validate(payload, path)
    return config, features


def _validate(payload: object, path: str | Path) -> tuple[ModelConfig, FeatureSpec, MaterialUNet]:
    """`validate_payload`, also returning the network built on the meta device to check the shapes."""
    import math

    import numpy as np

    import torch

    from ..field import BASE_FEATURES, DENSITY_CHANNELS
    from ..limits import require_memory
    from ..materials import NUM_CLASSES

    def bad(msg: str) -> InputError:
        return InputError(f"damaged checkpoint: {msg}", path)

    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise InputError(f"not a pixie-gs material checkpoint (format must be '{FORMAT}')", path)
    version = payload.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= FORMAT_VERSION:
        raise bad(f"format_version must be an integer 1..{FORMAT_VERSION}, got {version!r:.40}")
    missing = [k for k in ("config", "features", "normalization", "state_dict") if k not in payload]
    if missing:
        raise bad(f"missing {', '.join(missing)}")
    if payload["normalization"] != normalization_ranges():
        raise InputError("checkpoint uses different (E, nu, density) normalisation ranges than this pixie-gs", path)
    cfg, feat, weights = payload["config"], payload["features"], payload["state_dict"]
    for name, value in (("config", cfg), ("features", feat), ("state_dict", weights)):
        if not isinstance(value, dict):
            raise bad(f"'{name}' must be a mapping, got {type(value).__name__}")

    def integer(d: dict, key: str, lo: int, hi: int, where: str) -> int:
        v = d.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise bad(f"{where}.{key} must be an integer {lo}..{hi}, got {v!r:.40}")
        return v

    def number(d: dict, key: str, lo: float, hi: float, where: str) -> float:
        v = d.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            raise bad(f"{where}.{key} must be a number in [{lo:g}, {hi:g}], got {v!r:.40}")
        return float(v)

    def names(d: dict, key: str, where: str, allow_empty: bool) -> list[str]:
        v = d.get(key)
        if (not isinstance(v, (list, tuple)) or not all(isinstance(x, str) and 0 < len(x) <= 200 for x in v)
                or (not v and not allow_empty) or len(v) > 4096):
            raise bad(f"{where}.{key} must be a list of channel names, got {v!r:.60}")
        return list(v)

    extra_names = names(feat, "extra_names", "features", allow_empty=True)
    features = FeatureSpec(integer(feat, "resolution", *RESOLUTION_RANGE, "features"),
                           number(feat, "filter_voxels", 0.0, 10.0, "features"),
                           number(feat, "margin", 0.0, 0.45, "features"), tuple(extra_names))
    inputs = names(cfg, "input_channels", "config", allow_empty=False)
    known = set(DENSITY_CHANNELS + BASE_FEATURES) | set(extra_names)
    unknown = [c for c in inputs if c not in known]
    if unknown:
        raise bad(f"config.input_channels names unknown channel '{unknown[0]:.40}'")
    mult = cfg.get("multipliers", [1, 2, 4])
    if (not isinstance(mult, list) or not 1 <= len(mult) <= MAX_LEVELS
            or not all(isinstance(m, int) and not isinstance(m, bool) and MULTIPLIER_RANGE[0] <= m <= MULTIPLIER_RANGE[1]
                       for m in mult)):
        raise bad(f"config.multipliers must be 1..{MAX_LEVELS} integers in {MULTIPLIER_RANGE}, got {mult!r:.60}")
    defaults = ModelConfig(input_channels=inputs)
    ints = {}
    for key, lo, hi in (("projector_hidden", *CHANNELS_RANGE), ("projector_out", *CHANNELS_RANGE),
                        ("base_channels", *CHANNELS_RANGE), ("res_blocks", 0, MAX_RES_BLOCKS),
                        ("context_width", 0, CHANNELS_RANGE[1]),
                        ("num_classes", NUM_CLASSES, NUM_CLASSES), ("num_physical", 3, 3)):
        ints[key] = integer({key: cfg.get(key, getattr(defaults, key))}, key, lo, hi, "config")
    dropout = number({"dropout": cfg.get("dropout", 0.0)}, "dropout", 0.0, 0.99, "config")
    if features.resolution % (2 ** (len(mult) - 1)):
        raise bad(f"features.resolution {features.resolution} is not divisible by 2^{len(mult) - 1} "
                  f"({len(mult)} U-Net levels)")
    config = ModelConfig(input_channels=inputs, multipliers=list(mult), dropout=dropout, **ints)
    # weights: every entry a tensor, floating ones finite, shapes those of the config (checked on the
    # meta device, so a hostile config allocates nothing)
    for key, value in weights.items():
        if not isinstance(key, str) or not isinstance(value, torch.Tensor):
            raise bad(f"state_dict entry {key!r:.40} is not a named tensor")
    floating = [(k, v) for k, v in weights.items() if v.is_floating_point()]
    flat = [v.detach().reshape(-1).float().cpu().numpy() for _, v in floating]
    if flat and not np.isfinite(np.concatenate(flat)).all():  # one pass (numpy: no thread pool per tensor)
        key, value = next((k, v) for (k, v), a in zip(floating, flat) if not np.isfinite(a).all())
        raise bad(f"weight '{key}' holds NaN or inf ({int((~torch.isfinite(value)).sum())} values)")
    with torch.device("meta"):
        meta_model = MaterialUNet(config)
    shapes = {k: tuple(v.shape) for k, v in meta_model.state_dict().items()}
    stored = {k: tuple(v.shape) for k, v in weights.items()}
    if shapes != stored:
        diff = sorted(set(shapes) ^ set(stored)) or [k for k in shapes if shapes[k] != stored[k]]
        raise bad(f"weights do not match the stored config (first difference: '{diff[0]:.60}')")
    n = features.resolution ** 3
    widest = ints["base_channels"] * max(mult)
    activations = 4 * n * (len(known) + 2 * ints["projector_hidden"] + ints["projector_out"]
                           + 4 * ints["base_channels"] * mult[0]) + 4 * (n // 8) * 4 * widest
    require_memory(activations + 4 * sum(math.prod(s) for s in shapes.values()),
                   f"the checkpoint's {features.resolution}³ grid and network", path)
    return config, features, meta_model


def state_path(checkpoint: str | Path) -> Path:
    """Sidecar file holding the optimiser/epoch state for `pixie train --resume`."""
    return Path(str(checkpoint) + ".state.pt")


def load_training_state(path: str | Path) -> dict:
    """The `--resume` sidecar (model/optimiser state, epoch, step, history), checked: one-line
    InputError for an unreadable file, a missing or mistyped entry, or NaN/inf model weights."""
    import json

    import torch

    path = Path(path)
    state = load_weights_only(path, "training state")
    types = {"model": dict, "optimizer": dict, "epoch": int, "step": int, "elapsed_s": (int, float),
             "best_score": (int, float), "history_json": str, "extra_names": (list, tuple)}
    if not isinstance(state, dict):
        raise InputError("damaged training state (not a mapping)", path)
    for key, kind in types.items():
        if key not in state or isinstance(state[key], bool) or not isinstance(state[key], kind):
            raise InputError(f"damaged training state ('{key}' missing or of the wrong type)", path)
    if not all(isinstance(v, torch.Tensor) and (not v.is_floating_point() or bool(torch.isfinite(v).all()))
               for v in state["model"].values()):
        raise InputError("damaged training state (model weights that are not finite tensors)", path)
    try:
        json.loads(state["history_json"])
    except (ValueError, RecursionError):
        raise InputError("damaged training state (history is not JSON)", path) from None
    return state
