"""SuperSplat / PlayCanvas compressed `.ply` (`chunk` + packed `vertex` + optional `sh` elements).

Layout (binary little endian, as SuperSplat and splat-transform write it):
- `chunk` (one per 256 Gaussians, in file order): float min_x min_y min_z max_x max_y max_z,
  min_scale_x..z max_scale_x..z (log std-dev), and in newer files min_r min_g min_b max_r max_g max_b
  (colour range; 12-property files store colour unscaled in [0, 1]);
- `vertex`: uint packed_position, packed_rotation, packed_scale, packed_color;
  position and scale: 11/10/11 bits (x in bits 21–31, y 11–20, z 0–10) as unorm t, value = lerp(min, max, t);
  rotation: 2-bit index (bits 30–31) of the largest |component| of (rot_0..3) = (w, x, y, z), then the
  other three in that order, 10 bits each (bits 20–29, 10–19, 0–9), value = (t − 0.5)·√2;
  colour: r, g, b, α as 8-bit unorms (bits 24–31, 16–23, 8–15, 0–7); rgb = lerp(chunk range, t),
  f_dc = (rgb − 0.5)/SH_C0, α is the opacity itself (logit taken here, ±40 at 0 and 1);
- `sh` (optional): uchar f_rest_0..N (9, 24 or 45, same channel-major order as INRIA PLY),
  value = byte·8/255 − 4.
The writer orders Gaussians along a Morton curve first (as SuperSplat does) so each 256-Gaussian
chunk is spatially compact and its ranges small; `keep_order=True` writes them in cloud order.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import InputError
from ..splat import SH_C0, SplatCloud
from .ply_header import PlyHeader, check_binary_size, read_header

CHUNK = 256
CHUNK_PROPS = ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
               "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z"]
CHUNK_COLOUR_PROPS = ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"]
PACKED_PROPS = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]
OPACITY_LOGIT_LIMIT = 40.0  # logit written for α = 0 or 1 (what the PlayCanvas decompressor uses)
SH_RANGE = 4.0  # f_rest bytes cover [-4, 4]
LOG_SCALE_LIMIT = 40.0  # |log σ| kept (infinite scales would break the chunk ranges)


def is_compressed(header: PlyHeader) -> bool:
    """True when the header has a `chunk` element and a `vertex` element with the packed properties."""
    vertex = header.element("vertex")
    return (header.element("chunk") is not None and vertex is not None
            and all(p in vertex.names for p in PACKED_PROPS))


def _unorm(bits: np.ndarray, n: int) -> np.ndarray:
    return (bits & ((1 << n) - 1)).astype(np.float64) / ((1 << n) - 1)


def _unpack_111011(packed: np.ndarray) -> np.ndarray:
    return np.stack([_unorm(packed >> 21, 11), _unorm(packed >> 11, 10), _unorm(packed, 11)], axis=1)


def _unpack_rotation(packed: np.ndarray) -> np.ndarray:
    """Quaternions (N,4) in rot_0..3 order from the 2+10+10+10-bit smallest-three encoding."""
    small = np.stack([_unorm(packed >> 20, 10), _unorm(packed >> 10, 10), _unorm(packed, 10)], axis=1)
    small = (small - 0.5) * np.sqrt(2.0)
    largest = np.sqrt(np.maximum(0.0, 1.0 - np.sum(small * small, axis=1)))
    which = (packed >> 30).astype(np.int64)
    q = np.empty((len(packed), 4))
    cols = np.arange(4)
    for k in range(4):
        m = which == k
        others = cols[cols != k]
        q[np.ix_(m, others)] = small[m]
        q[m, k] = largest[m]
    return q


def read(path: str | Path) -> SplatCloud:
    """Decompress a SuperSplat/PlayCanvas compressed PLY into a validated SplatCloud."""
    path = Path(path)
    header = read_header(path)
    if header.format != "binary_little_endian":
        raise InputError(f"compressed PLY must be binary_little_endian (found {header.format})", path)
    chunk_el, vertex_el, sh_el = header.element("chunk"), header.element("vertex"), header.element("sh")
    for el in header.elements:
        if el.has_list:
            raise InputError(f"compressed PLY element '{el.name}' has a list property", path)
    check_binary_size(header, path.stat().st_size, path)
    names = chunk_el.names
    needed = CHUNK_PROPS + (CHUNK_COLOUR_PROPS if len(names) > len(CHUNK_PROPS) else [])
    if names[: len(needed)] != needed or len(names) not in (12, 18):
        raise InputError(f"compressed PLY chunk element has unexpected properties ({' '.join(names)})", path)
    n = vertex_el.count
    n_chunks = -(-n // CHUNK)
    if chunk_el.count != n_chunks:
        raise InputError(f"compressed PLY has {chunk_el.count} chunks for {n} Gaussians "
                         f"(expected {n_chunks}, one per {CHUNK})", path)
    if sh_el is not None and sh_el.count != n:
        raise InputError(f"compressed PLY has {sh_el.count} sh rows for {n} Gaussians", path)

    raw = np.fromfile(path, dtype=np.uint8, offset=header.data_offset)
    offset = 0
    tables = {}
    for el in header.elements:
        dt = el.dtype("<")
        if dt.itemsize == 0:
            continue
        size = el.count * dt.itemsize
        tables[el.name] = raw[offset: offset + size].view(dt)
        offset += size
    chunks = np.stack([tables["chunk"][p].astype(np.float64) for p in names], axis=1)
    per = np.repeat(np.arange(n_chunks), CHUNK)[:n]
    ch = chunks[per]
    vt = tables["vertex"]

    def lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
        return lo * (1.0 - t) + hi * t

    means = lerp(ch[:, 0:3], ch[:, 3:6], _unpack_111011(vt["packed_position"].astype(np.uint32)))
    log_scales = lerp(ch[:, 6:9], ch[:, 9:12], _unpack_111011(vt["packed_scale"].astype(np.uint32)))
    rotations = _unpack_rotation(vt["packed_rotation"].astype(np.uint32))
    col = vt["packed_color"].astype(np.uint32)
    rgb = np.stack([_unorm(col >> 24, 8), _unorm(col >> 16, 8), _unorm(col >> 8, 8)], axis=1)
    if len(names) == 18:
        rgb = lerp(ch[:, 12:15], ch[:, 15:18], rgb)
    alpha = _unorm(col, 8)
    with np.errstate(divide="ignore"):
        logit = np.log(alpha) - np.log1p(-alpha)
    logit = np.clip(logit, -OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT)
    sh_rest = np.zeros((n, 0), np.float32)
    if sh_el is not None and sh_el.names:  # gsplat writes an `sh` element with no properties at SH degree 0
        k = len(sh_el.names)
        if k not in (9, 24, 45) or sh_el.names != [f"f_rest_{i}" for i in range(k)]:
            raise InputError(f"compressed PLY sh element has {k} properties; expected f_rest_0… (9, 24 or 45)",
                             path)
        sh = tables["sh"]
        sh_rest = np.stack([sh[f"f_rest_{i}"] for i in range(k)], axis=1).astype(np.float32)
        sh_rest = sh_rest * np.float32(2 * SH_RANGE / 255.0) - np.float32(SH_RANGE)
    extra_vertex = [p for p in vertex_el.names if p not in PACKED_PROPS]
    cloud = SplatCloud(
        means=means.astype(np.float32),
        log_scales=log_scales.astype(np.float32),
        rotations=rotations.astype(np.float32),
        opacity_logits=logit.astype(np.float32),
        sh_dc=((rgb - 0.5) / SH_C0).astype(np.float32),
        sh_rest=np.ascontiguousarray(sh_rest, np.float32),
        extras={p: np.ascontiguousarray(vt[p]) for p in extra_vertex},
        source=str(path),
    )
    cloud.property_order = cloud._default_order()
    cloud.source_format = "compressed_ply"
    cloud.validate()
    return cloud


# ---------------------------------------------------------------------------------------------- writing
def _spread_bits_10(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between each of the low 10 bits of `v` (for 30-bit Morton codes)."""
    v = v.astype(np.uint64) & np.uint64(0x3FF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x030000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x0300F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x030C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x09249249)
    return v


def morton_order(means: np.ndarray) -> np.ndarray:
    """Indices sorting positions (N,3) along a 30-bit Morton (Z-order) curve over their bounds."""
    p = np.asarray(means, np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    span = np.where(hi - lo > 0, hi - lo, 1.0)
    q = np.clip(((p - lo) / span * 1023.0).astype(np.int64), 0, 1023)
    code = (_spread_bits_10(q[:, 0]) << np.uint64(2)) | (_spread_bits_10(q[:, 1]) << np.uint64(1)) \
        | _spread_bits_10(q[:, 2])
    return np.argsort(code, kind="stable")


def _chunk_min_max(values: np.ndarray, n_chunks: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-chunk min and max of `values` (N, k), padding the last chunk with its last row."""
    n = len(values)
    pad = n_chunks * CHUNK - n
    v = np.concatenate([values, np.repeat(values[-1:], pad, axis=0)]) if pad else values
    v = v.reshape(n_chunks, CHUNK, -1)
    return v.min(axis=1), v.max(axis=1)


def _pack_unorm(t: np.ndarray, bits: int) -> np.ndarray:
    top = (1 << bits) - 1
    return np.clip(np.floor(t * top + 0.5), 0, top).astype(np.uint32)


def _normalise(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    span = hi - lo
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(span < 1e-5, 0.0, (x - lo) / np.where(span < 1e-5, 1.0, span))
    return np.clip(t, 0.0, 1.0)


def _pack_111011(t: np.ndarray) -> np.ndarray:
    return (_pack_unorm(t[:, 0], 11) << 21) | (_pack_unorm(t[:, 1], 10) << 11) | _pack_unorm(t[:, 2], 11)


def _pack_rotation(rotations: np.ndarray) -> np.ndarray:
    q = np.asarray(rotations, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    which = np.argmax(np.abs(q), axis=1)
    q *= np.where(q[np.arange(len(q)), which] < 0, -1.0, 1.0)[:, None]
    out = which.astype(np.uint32)
    cols = np.arange(4)
    small = np.empty((len(q), 3))
    for k in range(4):
        m = which == k
        small[m] = q[np.ix_(m, cols[cols != k])]
    for j in range(3):
        out = (out << 10) | _pack_unorm(small[:, j] / np.sqrt(2.0) + 0.5, 10)
    return out


def encode(cloud: SplatCloud, keep_order: bool = False) -> tuple[bytes, np.ndarray]:
    """The compressed-PLY bytes of `cloud` and the Gaussian order used (indices into the cloud)."""
    n = len(cloud)
    order = np.arange(n) if keep_order else morton_order(cloud.means)
    n_chunks = -(-n // CHUNK)
    per = np.repeat(np.arange(n_chunks), CHUNK)[:n]
    means = cloud.means[order].astype(np.float64)
    log_scales = np.clip(cloud.log_scales[order].astype(np.float64), -LOG_SCALE_LIMIT, LOG_SCALE_LIMIT)
    rgb = 0.5 + SH_C0 * cloud.sh_dc[order].astype(np.float64)
    p_lo, p_hi = _chunk_min_max(means, n_chunks)
    s_lo, s_hi = _chunk_min_max(log_scales, n_chunks)
    c_lo, c_hi = _chunk_min_max(rgb, n_chunks)
    chunk_table = np.concatenate([p_lo, p_hi, s_lo, s_hi, c_lo, c_hi], axis=1).astype("<f4")
    vertex = np.empty((n, 4), "<u4")
    vertex[:, 0] = _pack_111011(_normalise(means, p_lo[per], p_hi[per]))
    vertex[:, 1] = _pack_rotation(cloud.rotations[order])
    vertex[:, 2] = _pack_111011(_normalise(log_scales, s_lo[per], s_hi[per]))
    tc = _normalise(rgb, c_lo[per], c_hi[per])
    alpha = cloud.opacities[order].astype(np.float64)
    vertex[:, 3] = ((_pack_unorm(tc[:, 0], 8) << 24) | (_pack_unorm(tc[:, 1], 8) << 16)
                    | (_pack_unorm(tc[:, 2], 8) << 8) | _pack_unorm(alpha, 8))
    k = cloud.sh_rest.shape[1]
    lines = ["ply", "format binary_little_endian 1.0", "comment Generated by pixie-gs",
             f"element chunk {n_chunks}"]
    lines += [f"property float {p}" for p in CHUNK_PROPS + CHUNK_COLOUR_PROPS]
    lines += [f"element vertex {n}"] + [f"property uint {p}" for p in PACKED_PROPS]
    body = [chunk_table.tobytes(), vertex.tobytes()]
    if k:
        lines += [f"element sh {n}"] + [f"property uchar f_rest_{i}" for i in range(k)]
        sh = cloud.sh_rest[order]  # float32 (45 values per Gaussian): floor(t·255 + 0.5), t = (v + 4)/8
        t = (sh + np.float32(SH_RANGE)) * np.float32(255.0 / (2 * SH_RANGE)) + np.float32(0.5)
        body.append(np.clip(np.floor(t), 0, 255).astype(np.uint8).tobytes())
    lines.append("end_header\n")
    return "\n".join(lines).encode("ascii") + b"".join(body), order


def write(cloud: SplatCloud, path: str | Path, keep_order: bool = False) -> None:
    """Write `cloud` as a compressed PLY (SuperSplat viewable), atomically.

    Extra per-Gaussian properties (materials, roles…) are not part of the format and are dropped.
    """
    cloud.validate()
    data, _ = encode(cloud, keep_order)
    with atomic_path(path, suffix=".ply.tmp") as tmp:
        tmp.write_bytes(data)
