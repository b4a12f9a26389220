"""antimatter15 `.splat`: headerless 32-byte records, one per Gaussian (web viewers' format).

Record (little endian): position 3×f32 (m), scale 3×f32 (linear std-dev, not log), colour
r, g, b, α as u8 (rgb = 0.5 + SH_C0·f_dc; α = opacity), rotation u8 ×4 in w, x, y, z order with
q = (byte − 128)/128 (normalised on read). No SH beyond degree 0, no extra properties.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import InputError
from ..splat import SH_C0, SplatCloud

RECORD = np.dtype([("position", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))])
MIN_SCALE = 1e-12  # scales of 0 (underflowed exports) are read as this (log σ ≈ −27.6), not as log(0)
OPACITY_LOGIT_LIMIT = 40.0


def read(path: str | Path) -> SplatCloud:
    """Read a `.splat` file into a validated SplatCloud (SH degree 0, log scales, logit opacity)."""
    path = Path(path)
    size = path.stat().st_size
    if size == 0 or size % RECORD.itemsize:
        raise InputError(f"is not an antimatter15 .splat file: size {size} bytes is not a positive multiple "
                         f"of {RECORD.itemsize}", path)
    rec = np.fromfile(path, dtype=RECORD)
    q = (rec["rot"].astype(np.float32) - 128.0) / 128.0
    norm = np.linalg.norm(q, axis=1)
    q[norm == 0] = (1.0, 0.0, 0.0, 0.0)
    rgba = rec["rgba"].astype(np.float64) / 255.0
    with np.errstate(divide="ignore"):
        logit = np.log(rgba[:, 3]) - np.log1p(-rgba[:, 3])
        log_scales = np.log(np.maximum(rec["scale"].astype(np.float64), MIN_SCALE))
    cloud = SplatCloud(
        means=np.ascontiguousarray(rec["position"], np.float32),
        log_scales=log_scales.astype(np.float32),
        rotations=q.astype(np.float32),
        opacity_logits=np.clip(logit, -OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT).astype(np.float32),
        sh_dc=((rgba[:, :3] - 0.5) / SH_C0).astype(np.float32),
        sh_rest=np.zeros((len(rec), 0), np.float32),
        source=str(path),
    )
    cloud.property_order = cloud._default_order()
    cloud.source_format = "splat"
    cloud.validate()
    return cloud


def encode(cloud: SplatCloud) -> bytes:
    """The `.splat` bytes of `cloud` in cloud order (colour, opacity and rotation rounded to 8 bits)."""
    rec = np.empty(len(cloud), RECORD)
    rec["position"] = cloud.means
    rec["scale"] = np.exp(cloud.log_scales.astype(np.float64)).astype(np.float32)
    rgba = np.concatenate([cloud.rgb().astype(np.float64), cloud.opacities[:, None].astype(np.float64)], axis=1)
    rec["rgba"] = np.clip(np.rint(rgba * 255.0), 0, 255).astype(np.uint8)
    q = cloud.quats.astype(np.float64)
    rec["rot"] = np.clip(np.rint(q * 128.0 + 128.0), 0, 255).astype(np.uint8)
    return rec.tobytes()


def write(cloud: SplatCloud, path: str | Path) -> None:
    """Write `cloud` as `.splat` atomically (SH rest and extra properties are not part of the format)."""
    cloud.validate()
    data = encode(cloud)
    with atomic_path(path, suffix=".splat.tmp") as tmp:
        tmp.write_bytes(data)
