"""Real 3D Gaussian splat rendering: what a splat viewer shows, for files, frames and the demo.

- `camera`: pinhole cameras (orbit / fixed framing, INRIA cameras.json, nerfstudio transforms.json);
- `raster`: EWA projection, SH colour and tile-sorted compositing (torch + a Warp kernel, CPU or
  CUDA from the same code); `reference`: the slow per-pixel definition the tests compare against;
- `video`: PNG / GIF / MP4 output.

Modes colour the same Gaussians differently: `colour` (the splat's own view-dependent SH
colour), `material` (predicted class), `logE` (log10 Young's modulus), `confidence` (a per-Gaussian
`confidence` attribute in [0, 1], where the file has one).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .camera import Camera, look_at, orbit_cameras, read_cameras, robust_sphere
from .raster import Gaussians, project, rasterize, render, render_many, view_colours

MODES = ("colour", "material", "logE", "confidence")
MODE_LABELS = {"colour": "colour", "material": "material", "logE": "log10 E", "confidence": "confidence"}
CONFIDENCE_ATTRIBUTES = ("confidence", "material_confidence")

__all__ = ["Camera", "Gaussians", "MODES", "look_at", "orbit_cameras", "read_cameras", "robust_sphere",
           "project", "rasterize", "render", "render_many", "view_colours", "available_modes", "mode_colours",
           "render_modes", "to_uint8"]


def available_modes(cloud) -> list[str]:
    """The modes this cloud can be shown in (colour always; the others need their attributes)."""
    modes = ["colour"]
    if cloud.has("material_id"):
        modes.append("material")
    if cloud.has("E"):
        modes.append("logE")
    if any(cloud.has(a) for a in CONFIDENCE_ATTRIBUTES):
        modes.append("confidence")
    return modes


def mode_colours(cloud, mode: str) -> np.ndarray | None:
    """Per-Gaussian RGB (N,3) in [0,1] for `mode`, or None for the SH colour (InputError when the
    cloud lacks the attribute the mode shows)."""
    from .. import viz

    if mode not in MODES:
        raise InputError(f"unknown render mode '{mode}' (choose from {', '.join(MODES)})")
    if mode == "colour":
        return None
    if mode not in available_modes(cloud):
        need = {"material": "material_id", "logE": "E", "confidence": "confidence"}[mode]
        raise InputError(f"mode '{mode}' needs a per-Gaussian '{need}' attribute (run `pixie annotate` "
                         "first)", cloud.source)
    if mode == "material":
        return viz.material_colors(cloud.get("material_id"))
    if mode == "logE":
        return viz.log_e_colors(cloud.get("E"))
    from matplotlib import colormaps

    name = next(a for a in CONFIDENCE_ATTRIBUTES if cloud.has(a))
    return colormaps["magma"](np.clip(np.asarray(cloud.get(name), np.float64), 0, 1))[:, :3].astype(np.float32)


def to_uint8(image) -> np.ndarray:
    """A float image in [0,1] (torch or numpy) as uint8 (H,W,3)."""
    arr = image.detach().cpu().numpy() if hasattr(image, "detach") else np.asarray(image)
    return np.round(np.clip(arr, 0.0, 1.0) * 255.0).astype(np.uint8)


def render_modes(cloud, cam: Camera, modes: list[str], device: str = "cpu",
                 background: tuple[float, float, float] = (1.0, 1.0, 1.0),
                 gaussians: Gaussians | None = None) -> list[np.ndarray]:
    """One uint8 image (H,W,3) per mode of `cloud` seen by `cam` (InputError if a result is not
    finite, e.g. NaN in the file)."""
    g = gaussians if gaussians is not None else Gaussians.from_cloud(cloud, device)
    images = render_many(g, cam, [mode_colours(cloud, mode) for mode in modes], background=background)
    out = []
    for image in images:
        arr = image.detach().cpu().numpy()  # checked in numpy: torch's threads crawl on a busy CPU
        if not np.isfinite(arr).all():
            raise InputError("rendering gave non-finite pixels (NaN or inf in the Gaussians)", cloud.source)
        out.append(to_uint8(arr))
    return out


def frame_files(frames_dir: str | Path) -> list[Path]:
    """The `frame_*.ply` files of a simulation output directory, in frame order."""
    from ..sim.frames import FRAME_PATTERN

    frames_dir = Path(frames_dir)
    files = sorted((p for p in frames_dir.iterdir() if FRAME_PATTERN.fullmatch(p.name)),
                   key=lambda p: int(FRAME_PATTERN.fullmatch(p.name).group(1)))
    if not files:
        raise InputError("holds no frame_*.ply files (the output of `pixie simulate`)", frames_dir)
    return files
