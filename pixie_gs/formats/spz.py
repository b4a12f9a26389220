"""Niantic `.spz`: quantised Gaussians, gzip (versions 1–3) or per-stream ZSTD (version 4).

Header (little endian): magic "NGSP" (0x5053474e), version u32, numPoints u32, shDegree u8,
fractionalBits u8, flags u8 (0x1 antialiased, 0x2 extensions), then a reserved byte (versions
1–3: 16 bytes, the whole file gzip-compressed) or numStreams u8, tocByteOffset u32 and 12
reserved bytes (version 4: 32 plaintext bytes, a table of (compressed, uncompressed) u64 sizes
at tocByteOffset, then one ZSTD frame per non-empty attribute).
Attributes, in this order, each for all points: positions (24-bit signed fixed point with
`fractionalBits`, 3 per point; version 1: float16), alphas (u8, α·255), colours (u8, SH DC
coefficient f_dc = (c/255 − 0.5)/0.15), scales (u8, log σ = s/16 − 10), rotations (version ≥ 3:
4 bytes, 2-bit index of the largest |component| of (x, y, z, w) and three 10-bit sign+magnitude
values of √½·m/511, the first remaining component in the highest bits; version 2: x, y, z as
c/127.5 − 1 with w ≥ 0), SH (u8, (c − 128)/128, coefficient-major with the colour channel inner).
Axes: .spz stores right-up-back (RUB); 3DGS PLY is right-down-front (RDF). As Niantic's own
PLY tools do, reading flips y and z (positions, quaternion x/y/z signs (1, −1, −1), SH signs per
coefficient) and writing flips them back, so a capture keeps its orientation through a round trip.
"""
from __future__ import annotations

import gzip
import struct
import zlib
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import InputError
from ..splat import SplatCloud

MAGIC = 0x5053474E
COLOR_SCALE = 0.15
SH_DIM = {0: 0, 1: 3, 2: 8, 3: 15, 4: 24}
OPACITY_LOGIT_LIMIT = 40.0
# RUB <-> RDF sign flips (self-inverse): positions, quaternion (w, x, y, z), SH coefficients 0..14
AXIS_FLIP = np.array([1.0, -1.0, -1.0])
QUAT_FLIP = np.array([1.0, 1.0, -1.0, -1.0])
SH_FLIP = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], np.float32)
FRACTIONAL_BITS = 12  # written: 1/4096 m steps, ±2048 m range (what Niantic's packer uses)


def _decompress(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """(header fields, raw attribute byte arrays) of the .spz at `path`."""
    raw = path.read_bytes()
    if raw[:4] == b"NGSP":
        return _streams_v4(raw, path)
    try:
        data = gzip.decompress(raw)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"damaged .spz (gzip: {exc})", path) from None
    if len(data) < 16:
        raise InputError("damaged .spz (header shorter than 16 bytes)", path)
    magic, version, n, sh_degree, frac, flags, _ = struct.unpack_from("<IIIBBBB", data)
    head = _check_header(magic, version, n, sh_degree, path)
    head.update(n=n, sh_degree=sh_degree, frac=frac, flags=flags, version=version)
    sizes = _attribute_sizes(head)
    need = 16 + sum(sizes.values())
    if len(data) < need:
        raise InputError(f"truncated .spz: {n} points need {need} bytes, the data holds {len(data)}", path)
    arrays, off = {}, 16
    for name, size in sizes.items():
        arrays[name] = np.frombuffer(data, np.uint8, size, off)
        off += size
    return head, arrays


def _check_header(magic: int, version: int, n: int, sh_degree: int, path: Path) -> dict:
    if magic != MAGIC:
        raise InputError("not a .spz file (no NGSP magic)", path)
    if version not in (1, 2, 3, 4):
        raise InputError(f".spz version {version} is not supported (1–4 are)", path)
    if sh_degree not in SH_DIM:
        raise InputError(f".spz SH degree {sh_degree} is not 0–4", path)
    if sh_degree == 4:
        raise InputError(".spz with SH degree 4 is not supported (3DGS PLY holds degree ≤ 3)", path)
    return {}


def _attribute_sizes(head: dict) -> dict[str, int]:
    n, version = head["n"], head["version"]
    return {
        "positions": n * 3 * (2 if version == 1 else 3),
        "alphas": n,
        "colors": n * 3,
        "scales": n * 3,
        "rotations": n * (4 if version >= 3 else 3),
        "sh": n * SH_DIM[head["sh_degree"]] * 3,
    }


def _streams_v4(raw: bytes, path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    if len(raw) < 32:
        raise InputError("damaged .spz (header shorter than 32 bytes)", path)
    magic, version, n, sh_degree, frac, flags, n_streams, toc = struct.unpack_from("<IIIBBBBI", raw)
    head = _check_header(magic, version, n, sh_degree, path)
    head.update(n=n, sh_degree=sh_degree, frac=frac, flags=flags, version=version)
    try:
        import zstandard
    except ImportError:
        raise InputError(".spz version 4 is ZSTD-compressed: install the `zstandard` package to read it",
                         path) from None
    sizes = {k: v for k, v in _attribute_sizes(head).items() if v}
    if n_streams != len(sizes) or toc + 16 * n_streams > len(raw):
        raise InputError(f"damaged .spz: {n_streams} streams where {len(sizes)} attributes are expected", path)
    table = np.frombuffer(raw, "<u8", 2 * n_streams, toc).reshape(-1, 2)
    off = toc + 16 * n_streams
    arrays = {}
    dctx = zstandard.ZstdDecompressor()
    for (name, size), (csize, usize) in zip(sizes.items(), table):
        if usize != size or off + int(csize) > len(raw):
            raise InputError(f"damaged .spz: stream '{name}' has {int(usize)} bytes, {size} expected", path)
        try:
            data = dctx.decompress(raw[off: off + int(csize)], max_output_size=size)
        except zstandard.ZstdError as exc:
            raise InputError(f"damaged .spz stream '{name}' ({exc})", path) from None
        if len(data) != size:
            raise InputError(f"damaged .spz: stream '{name}' decompressed to {len(data)} of {size} bytes", path)
        arrays[name] = np.frombuffer(data, np.uint8)
        off += int(csize)
    if off != len(raw):
        raise InputError(f"damaged .spz: {len(raw) - off} unexpected bytes after the last stream", path)
    return head, arrays


def _rotations_smallest_three(r: np.ndarray) -> np.ndarray:
    """(N,4) x,y,z,w from 4-byte smallest-three codes."""
    comp = r.reshape(-1, 4).astype(np.uint32)
    comp = comp[:, 0] | (comp[:, 1] << 8) | (comp[:, 2] << 16) | (comp[:, 3] << 24)
    largest = (comp >> 30).astype(np.int64)
    q = np.zeros((len(comp), 4))
    rest = comp.copy()
    for i in range(3, -1, -1):  # the last remaining component sits in the lowest 10 bits
        take = largest != i
        mag = (rest & 511).astype(np.float64)
        neg = ((rest >> 9) & 1).astype(bool)
        val = np.sqrt(0.5) * mag / 511.0
        q[take, i] = np.where(neg, -val, val)[take]
        rest = np.where(take, rest >> 10, rest)
    q[np.arange(len(q)), largest] = np.sqrt(np.maximum(0.0, 1.0 - np.sum(q * q, axis=1)))
    return q


def read(path: str | Path) -> SplatCloud:
    """Read a Niantic `.spz` (versions 1–4, SH degree 0–3) into a validated SplatCloud."""
    path = Path(path)
    head, a = _decompress(path)
    n, deg = head["n"], head["sh_degree"]
    if head["version"] == 1:
        means = a["positions"].view("<f2").reshape(n, 3).astype(np.float64)
    else:
        p = a["positions"].reshape(n, 3, 3).astype(np.int32)
        fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
        fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)  # sign-extend 24 bits
        means = fixed.astype(np.float64) / (1 << head["frac"])
    alpha = a["alphas"].astype(np.float64) / 255.0
    with np.errstate(divide="ignore"):
        logit = np.clip(np.log(alpha) - np.log1p(-alpha), -OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT)
    f_dc = (a["colors"].reshape(n, 3).astype(np.float64) / 255.0 - 0.5) / COLOR_SCALE
    log_scales = a["scales"].reshape(n, 3).astype(np.float64) / 16.0 - 10.0
    if head["version"] >= 3:
        xyzw = _rotations_smallest_three(a["rotations"])
    else:
        xyz = a["rotations"].reshape(n, 3).astype(np.float64) / 127.5 - 1.0
        xyzw = np.concatenate([xyz, np.sqrt(np.maximum(0.0, 1.0 - np.sum(xyz * xyz, axis=1)))[:, None]], axis=1)
    wxyz = xyzw[:, [3, 0, 1, 2]] * QUAT_FLIP
    means = means * AXIS_FLIP
    dim = SH_DIM[deg]
    sh = (a.get("sh", np.zeros(0, np.uint8)).reshape(n, dim, 3).astype(np.float32) - 128.0) / 128.0
    sh *= SH_FLIP[:dim, None]
    sh_rest = sh.transpose(0, 2, 1).reshape(n, 3 * dim)  # to INRIA's channel-major f_rest order
    cloud = SplatCloud(
        means=means.astype(np.float32), log_scales=log_scales.astype(np.float32),
        rotations=wxyz.astype(np.float32), opacity_logits=logit.astype(np.float32),
        sh_dc=f_dc.astype(np.float32), sh_rest=np.ascontiguousarray(sh_rest, np.float32), source=str(path),
    )
    cloud.property_order = cloud._default_order()
    cloud.source_format = "spz"
    if head["flags"] & 0x1:
        cloud.set("spz_antialiased", np.ones(n, np.uint8), np.uint8)
    cloud.validate()
    return cloud


def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def _pack_smallest_three(wxyz: np.ndarray) -> np.ndarray:
    q = np.asarray(wxyz, np.float64)[:, [1, 2, 3, 0]]
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    largest = np.argmax(np.abs(q), axis=1)
    q *= np.where(q[np.arange(len(q)), largest] < 0, -1.0, 1.0)[:, None]
    comp = largest.astype(np.uint32)
    for i in range(4):
        take = largest != i
        mag = np.clip(np.floor(511.0 * np.abs(q[:, i]) / np.sqrt(0.5) + 0.5), 0, 511).astype(np.uint32)
        code = ((q[:, i] < 0).astype(np.uint32) << 9) | mag
        comp = np.where(take, (comp << 10) | code, comp)
    return comp.astype("<u4").view(np.uint8).reshape(-1, 4)


def encode(cloud: SplatCloud, version: int = 3) -> bytes:
    """The gzip-compressed `.spz` bytes (version 2 or 3) of `cloud`, in cloud order."""
    if version not in (2, 3):
        raise ValueError("pixie-gs writes .spz versions 2 and 3")
    n = len(cloud)
    deg = cloud.sh_degree
    scale = float(1 << FRACTIONAL_BITS)
    fixed = np.rint(cloud.means.astype(np.float64) * AXIS_FLIP * scale).astype(np.int64)
    limit = (1 << 23) - 1
    if np.abs(fixed).max(initial=0) > limit:
        raise InputError(f"positions beyond ±{limit / scale:.0f} m do not fit .spz's 24-bit fixed point",
                         cloud.source)
    fixed &= 0xFFFFFF
    positions = np.stack([fixed & 255, (fixed >> 8) & 255, (fixed >> 16) & 255], axis=-1).astype(np.uint8)
    alphas = _u8(cloud.opacities.astype(np.float64) * 255.0)
    colors = _u8(cloud.sh_dc.astype(np.float64) * (COLOR_SCALE * 255.0) + 0.5 * 255.0)
    scales = _u8((cloud.log_scales.astype(np.float64) + 10.0) * 16.0)
    if version >= 3:
        rotations = _pack_smallest_three(cloud.rotations.astype(np.float64) * QUAT_FLIP)
    else:
        q = (cloud.quats.astype(np.float64) * QUAT_FLIP)[:, [1, 2, 3, 0]]
        q *= np.where(q[:, 3] < 0, -1.0, 1.0)[:, None]
        rotations = _u8(q[:, :3] * 127.5 + 127.5)
    dim = SH_DIM[deg]
    sh = cloud.sh_rest.reshape(n, 3, dim).transpose(0, 2, 1) * SH_FLIP[:dim, None]  # float32: 45 per Gaussian
    sh_bytes = _u8(sh * np.float32(128.0) + np.float32(128.0))
    header = struct.pack("<IIIBBBB", MAGIC, version, n, deg, FRACTIONAL_BITS, 0, 0)
    body = b"".join(np.ascontiguousarray(x).tobytes() for x in (positions, alphas, colors, scales, rotations,
                                                                 sh_bytes))
    return gzip.compress(header + body, compresslevel=6, mtime=0)


def write(cloud: SplatCloud, path: str | Path, version: int = 3) -> None:
    """Write `cloud` as a gzip `.spz` (version 3 by default; 2 for old viewers), atomically."""
    cloud.validate()
    data = encode(cloud, version)
    with atomic_path(path, suffix=".spz.tmp") as tmp:
        tmp.write_bytes(data)
