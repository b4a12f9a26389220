"""Splat formats: decoding checked by independent plain decoders and hand-verified values,
round trips within each format's quantisation, detection by content, strict PLY parsing."""
from __future__ import annotations

import math
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from pixie_gs.errors import InputError
from pixie_gs.formats import detect_format, read_any, write_any
from pixie_gs.formats import compressed_ply
from pixie_gs.splat import SH_C0, SplatCloud, read_splat, write_splat

DATA = Path(__file__).parent / "data"
GUITAR = DATA / "guitar_slice.compressed.ply"  # 768 Gaussians of a real SuperSplat capture (MIT, see README)


def random_cloud(n: int = 1000, rest: int = 0, seed: int = 0, extras: bool = False) -> SplatCloud:
    """Gaussians in a 2 m box with varied sizes, colours, opacities and rotations."""
    rng = np.random.default_rng(seed)
    cloud = SplatCloud.from_arrays(
        rng.uniform(-1.0, 1.0, (n, 3)), log_scales=rng.uniform(-6.0, -1.0, (n, 3)),
        rotations=rng.normal(size=(n, 4)), opacity_logits=rng.uniform(-5.0, 5.0, n),
        rgb=rng.uniform(0.0, 1.0, (n, 3)), sh_rest=rng.uniform(-0.9, 0.9, (n, rest)))
    if extras:
        cloud.set_materials(rng.integers(0, 7, n), rng.uniform(1e3, 1e9, n), np.full(n, 0.3), np.full(n, 500))
    return cloud


def quat_angle(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Rotation angle (rad) between unit quaternions, sign-insensitive."""
    a = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    b = q2 / np.linalg.norm(q2, axis=1, keepdims=True)
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=1)), 0.0, 1.0))


# ------------------------------------------------------------------ compressed PLY: a real file
def plain_decode_compressed(path: Path) -> dict[str, np.ndarray]:
    """Independent decoder written from the published layout, one Gaussian at a time."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode().splitlines()
    n_chunks = int(next(l for l in lines if l.startswith("element chunk")).split()[2])
    n = int(next(l for l in lines if l.startswith("element vertex")).split()[2])
    chunks = [struct.unpack_from("<18f", raw, end + 72 * c) for c in range(n_chunks)]
    base = end + 72 * n_chunks
    out = {k: [] for k in ("xyz", "log_scale", "quat", "rgb", "alpha")}
    for i in range(n):
        pos, rot, scl, col = struct.unpack_from("<4I", raw, base + 16 * i)
        c = chunks[i // 256]
        t = [(pos >> 21) / 2047.0, ((pos >> 11) & 1023) / 1023.0, (pos & 2047) / 2047.0]
        out["xyz"].append([c[k] + (c[k + 3] - c[k]) * t[k] for k in range(3)])
        t = [(scl >> 21) / 2047.0, ((scl >> 11) & 1023) / 1023.0, (scl & 2047) / 2047.0]
        out["log_scale"].append([c[6 + k] + (c[9 + k] - c[6 + k]) * t[k] for k in range(3)])
        small = [(((rot >> s) & 1023) / 1023.0 - 0.5) * math.sqrt(2.0) for s in (20, 10, 0)]
        big = math.sqrt(max(0.0, 1.0 - sum(v * v for v in small)))
        q = list(small)
        q.insert(rot >> 30, big)  # the largest component goes back at its stored index (w, x, y, z)
        out["quat"].append(q)
        bytes4 = [(col >> 24) & 255, (col >> 16) & 255, (col >> 8) & 255, col & 255]
        out["rgb"].append([c[12 + k] + (c[15 + k] - c[12 + k]) * bytes4[k] / 255.0 for k in range(3)])
        out["alpha"].append(bytes4[3] / 255.0)
    return {k: np.array(v) for k, v in out.items()}


def test_real_compressed_slice_decodes_like_an_independent_decoder() -> None:
    cloud = read_splat(GUITAR)
    ref = plain_decode_compressed(GUITAR)
    assert cloud.source_format == "compressed_ply" and len(cloud) == 768 and cloud.sh_degree == 0
    np.testing.assert_allclose(cloud.means, ref["xyz"], atol=1e-6)
    np.testing.assert_allclose(cloud.log_scales, ref["log_scale"], atol=1e-5)
    np.testing.assert_allclose(cloud.rotations, ref["quat"], atol=1e-6)
    np.testing.assert_allclose(cloud.rgb(), np.clip(ref["rgb"], 0, 1), atol=1e-5)
    np.testing.assert_allclose(cloud.opacities, np.clip(ref["alpha"], 1e-17, 1 - 1e-7), atol=1e-6)


def test_real_compressed_slice_values_checked_by_hand() -> None:
    """Gaussian 0 of the guitar slice, decoded by hand from its bytes (comments show the working)."""
    raw = GUITAR.read_bytes()
    end = raw.index(b"end_header\n") + 11
    chunk0 = struct.unpack_from("<18f", raw, end)
    pos, rot, scl, col = struct.unpack_from("<4I", raw, end + 3 * 72)
    # packed_position 0x{pos:08x}: x = bits 31..21, y = bits 20..11, z = bits 10..0
    qx, qy, qz = pos >> 21, (pos >> 11) & 0x3FF, pos & 0x7FF
    cloud = read_splat(GUITAR)
    expect_x = chunk0[0] + (chunk0[3] - chunk0[0]) * qx / 2047
    expect_y = chunk0[1] + (chunk0[4] - chunk0[1]) * qy / 1023
    expect_z = chunk0[2] + (chunk0[5] - chunk0[2]) * qz / 2047
    assert cloud.means[0] == pytest.approx([expect_x, expect_y, expect_z], abs=1e-6)
    # the capture sits in the chunk's box, and the whole slice lies in the guitar's published box
    lo, hi = cloud.bounds()
    assert (lo >= np.array([-0.66, -4.3, -0.53]) - 0.05).all() and (hi <= np.array([0.83, 0.09, 0.93]) + 0.05).all()
    # alpha byte / 255 is the opacity
    assert cloud.opacities[0] == pytest.approx((col & 0xFF) / 255, abs=1e-6)
    # unit quaternions (the largest component is rebuilt from the three stored ones)
    np.testing.assert_allclose(np.linalg.norm(cloud.rotations, axis=1), 1.0, atol=1e-5)
    assert int(rot >> 30) == int(np.argmax(np.abs(cloud.rotations[0])))


def chunk_ranges(values: np.ndarray) -> np.ndarray:
    """Per-256-row chunk (max − min) of `values`, repeated per row (what the format quantises over)."""
    n = len(values)
    out = np.empty_like(values, dtype=np.float64)
    for s in range(0, n, 256):
        v = values[s:s + 256].astype(np.float64)
        out[s:s + 256] = v.max(axis=0) - v.min(axis=0)
    return out


def test_compressed_round_trip_within_quantisation(tmp_path: Path) -> None:
    cloud = random_cloud(1000, rest=9, extras=True)
    write_splat(cloud, tmp_path / "a.compressed.ply")
    assert detect_format(tmp_path / "a.compressed.ply") == "compressed_ply"
    compressed_ply.write(cloud, tmp_path / "b.ply", keep_order=True)
    back = read_splat(tmp_path / "b.ply")
    assert back.source_format == "compressed_ply" and back.sh_degree == 1 and not back.extras
    # 11/10/11-bit unorm over each chunk's range: |error| ≤ range / (2·(2^bits − 1)) (+ float32 rounding)
    steps = np.array([2047.0, 1023.0, 2047.0])
    pos_bound = chunk_ranges(cloud.means) / (2 * steps) + 1e-6
    assert (np.abs(back.means - cloud.means) <= pos_bound).all()
    scale_bound = chunk_ranges(cloud.log_scales) / (2 * steps) + 1e-5
    assert (np.abs(back.log_scales - cloud.log_scales) <= scale_bound).all()
    # colour: 8 bits over the chunk's rgb range; opacity: 8 bits over [0, 1]
    rgb = 0.5 + SH_C0 * cloud.sh_dc.astype(np.float64)
    assert (np.abs((0.5 + SH_C0 * back.sh_dc) - rgb) <= chunk_ranges(rgb) / 510 + 1e-5).all()
    assert np.abs(back.opacities - cloud.opacities).max() <= 0.5 / 255 + 1e-6
    # rotation: three 10-bit components of step √2/1023 are each off by ≤ ε = √2/2046 (|d| ≤ √3·ε); the
    # rebuilt largest one (≥ 1/2) by ≤ √3·|d|, so |q' − q| ≤ 2·√3·ε and the angle 2·|q' − q| ≤ 4·√3·ε ≈ 0.0048 rad
    assert quat_angle(back.rotations, cloud.rotations).max() <= 4 * math.sqrt(3) * math.sqrt(2) / 2046 + 1e-4
    # SH rest: 8 bits over [-4, 4]: |error| ≤ 4/255
    assert np.abs(back.sh_rest - cloud.sh_rest).max() <= 4 / 255 + 1e-6
    # the default writer reorders along a Morton curve; the values are the same Gaussians
    default = read_splat(tmp_path / "a.compressed.ply")
    _, order = compressed_ply.encode(cloud)
    assert sorted(order) == list(range(len(cloud)))
    assert np.abs(default.means - cloud.means[order]).max() <= 2.0 / 1023


def test_compressed_to_ply_and_back_keeps_the_real_bytes(tmp_path: Path) -> None:
    """Real file → INRIA PLY → compressed (file order): every packed value comes back within one step."""
    cloud = read_splat(GUITAR)
    write_splat(cloud, tmp_path / "g.ply")
    ply = read_splat(tmp_path / "g.ply")
    assert ply.source_format == "inria_ply"
    compressed_ply.write(ply, tmp_path / "g2.compressed.ply", keep_order=True)
    back = read_splat(tmp_path / "g2.compressed.ply")
    steps = np.array([2047.0, 1023.0, 2047.0])
    assert (np.abs(back.means - cloud.means) <= chunk_ranges(cloud.means) / (2 * steps) + 1e-6).all()
    assert np.abs(back.opacities - cloud.opacities).max() <= 0.5 / 255 + 1e-6
    assert quat_angle(back.rotations, cloud.rotations).max() <= 4 * math.sqrt(3) * math.sqrt(2) / 2046 + 1e-4


# ------------------------------------------------------------------ strict INRIA PLY
def write_inria(path: Path, n: int = 40, text: bool = False) -> Path:
    binary = path.with_suffix(".bin.ply") if text else path
    random_cloud(n).write(binary)
    if text:
        table = np.array(PlyData.read(str(binary))["vertex"].data)
        PlyData([PlyElement.describe(table, "vertex")], text=True).write(str(path))
    return path


def edit_vertex_count(path: Path, new_count: int) -> None:
    raw = path.read_bytes()
    end = raw.index(b"end_header")
    head = raw[:end].decode()
    old = next(l for l in head.splitlines() if l.startswith("element vertex"))
    path.write_bytes(head.replace(old, f"element vertex {new_count}").encode() + raw[end:])


@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("delta,needle", [(+1, "truncated"), (-1, "longer than its header")])
def test_vertex_count_disagreeing_with_data_is_an_input_error(tmp_path: Path, text: bool, delta: int,
                                                              needle: str) -> None:
    path = write_inria(tmp_path / "c.ply", 40, text)
    edit_vertex_count(path, 40 + delta)
    with pytest.raises(InputError) as err:
        read_splat(path)
    assert needle in str(err.value) and str(path) in str(err.value) and "\n" not in str(err.value)


def test_list_property_on_vertex_is_a_one_line_error(tmp_path: Path) -> None:
    table = np.empty(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("opacity", "f4"), ("ids", "O")])
    for k in ("x", "y", "z", "opacity"):
        table[k] = 0.0
    table["ids"] = [np.array([1, 2], np.int32)] * 3
    PlyData([PlyElement.describe(table, "vertex", val_types={"ids": "i4"})]).write(str(tmp_path / "l.ply"))
    proc = subprocess.run([sys.executable, "-m", "pixie_gs", "info", str(tmp_path / "l.ply")],
                          capture_output=True, text=True)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "list property 'ids'" in lines[0]


def test_element_named_twice_is_a_one_line_error(tmp_path: Path) -> None:
    """The real slice with a second, empty 'element vertex' line at the end of its header: the data size still
    matches the header, so only the header check can tell. Before the check this file read as valid, and the
    mutation fuzzing of compressed PLYs found a file with the line in another place that ended in a traceback."""
    raw = GUITAR.read_bytes()
    end = raw.index(b"end_header\n")
    head = raw[:end] + b"element vertex 768\n"
    assert head.count(b"element vertex 768") == 2
    path = tmp_path / "twice.compressed.ply"
    path.write_bytes(head + raw[end:])
    proc = subprocess.run([sys.executable, "-m", "pixie_gs", "info", str(path)], capture_output=True, text=True)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and "Traceback" not in proc.stderr and len(lines) == 1
    assert "element 'vertex' appears twice" in lines[0] and str(path) in lines[0]


# ------------------------------------------------------------------ detection by content
def test_detection_ignores_extensions(tmp_path: Path) -> None:
    cloud = random_cloud(300)
    written = {}
    for fmt in ("inria_ply", "compressed_ply", "splat", "spz"):
        path = tmp_path / f"scene_{fmt}.bin"  # no telling extension
        write_any(cloud, path, fmt)
        written[fmt] = path
    shutil.copy(written["splat"], tmp_path / "looks.ply")
    shutil.copy(written["spz"], tmp_path / "looks.splat")
    shutil.copy(written["compressed_ply"], tmp_path / "looks.spz")
    assert {fmt: detect_format(p) for fmt, p in written.items()} == {f: f for f in written}
    assert detect_format(tmp_path / "looks.ply") == "splat"
    assert detect_format(tmp_path / "looks.splat") == "spz"
    assert detect_format(tmp_path / "looks.spz") == "compressed_ply"
    assert read_any(tmp_path / "looks.ply").source_format == "splat"


def _unknown_files(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    import gzip

    cases = {}
    p = tmp_path / "model.splat"
    p.write_bytes(b"glTF" + struct.pack("<II", 2, 100) + bytes(88))
    cases["glb"] = (p, "glTF binary (mesh), not a splat: use `pixie convert")
    p = tmp_path / "notes.spz"
    p.write_bytes(gzip.compress(b"just some text, no magic here"))
    cases["gzip"] = (p, "is gzip but not .spz")
    p = tmp_path / "points.ply"
    pts = np.zeros(4, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1")])
    PlyData([PlyElement.describe(pts, "vertex")]).write(str(p))
    cases["point cloud"] = (p, "PLY point cloud without Gaussian properties")
    p = tmp_path / "random.ply"
    p.write_bytes(bytes(range(7, 107)))
    cases["unknown"] = (p, "unknown format (first bytes")
    p = tmp_path / "empty.splat"
    p.write_bytes(b"")
    cases["empty"] = (p, "is empty")
    return cases


def test_unknown_formats_give_one_line_naming_what_was_found(tmp_path: Path) -> None:
    for label, (path, needle) in _unknown_files(tmp_path).items():
        with pytest.raises(InputError) as err:
            read_splat(path)
        assert needle in str(err.value) and str(path) in str(err.value), (label, str(err.value))
        assert "\n" not in str(err.value)
    path, needle = _unknown_files(tmp_path)["glb"]
    proc = subprocess.run([sys.executable, "-m", "pixie_gs", "info", str(path)], capture_output=True, text=True)
    assert proc.returncode == 1 and proc.stdout == "" and len(proc.stderr.strip().splitlines()) == 1
    assert needle in proc.stderr


# ------------------------------------------------------------------ antimatter15 .splat
def test_splat_file_written_from_the_spec_reads_exactly(tmp_path: Path) -> None:
    """Two records packed by hand with struct from the published 32-byte layout."""
    recs = [((1.0, -2.0, 0.5), (0.01, 0.02, 0.04), (255, 0, 128, 191), (255, 128, 128, 128)),
            ((0.0, 0.0, 3.0), (1.0, 1.0, 1.0), (0, 51, 204, 64), (218, 128, 218, 128))]
    raw = b"".join(struct.pack("<3f3f4B4B", *p, *s, *c, *q) for p, s, c, q in recs)
    (tmp_path / "hand.splat").write_bytes(raw)
    cloud = read_splat(tmp_path / "hand.splat")
    assert cloud.source_format == "splat" and len(cloud) == 2 and cloud.sh_degree == 0
    np.testing.assert_array_equal(cloud.means, [r[0] for r in recs])
    np.testing.assert_allclose(cloud.scales, [r[1] for r in recs], rtol=1e-6)
    np.testing.assert_allclose(cloud.rgb(), [[1.0, 0.0, 128 / 255], [0.0, 0.2, 0.8]], atol=1e-6)
    np.testing.assert_allclose(cloud.opacities, [191 / 255, 64 / 255], atol=1e-6)
    # (255−128)/128 = 0.992 → identity; (218−128)/128 = 0.703 on w and y → 90° about y
    np.testing.assert_allclose(cloud.quats, [[1, 0, 0, 0], [math.sqrt(0.5), 0, math.sqrt(0.5), 0]], atol=1e-6)


def test_splat_round_trip_within_quantisation(tmp_path: Path) -> None:
    cloud = random_cloud(1000, rest=9, extras=True)
    write_splat(cloud, tmp_path / "s.splat")
    back = read_splat(tmp_path / "s.splat")
    assert len(back) == len(cloud) and back.sh_degree == 0 and not back.extras
    np.testing.assert_array_equal(back.means, cloud.means)  # float32 verbatim
    np.testing.assert_allclose(back.log_scales, cloud.log_scales, atol=1e-5)  # exp/log in float32
    assert np.abs(back.rgb() - cloud.rgb()).max() <= 0.5 / 255 + 1e-6  # 8-bit colour, rounded
    assert np.abs(back.opacities - cloud.opacities).max() <= 0.5 / 255 + 1e-6
    # each quaternion component off by ≤ 1/128 (rounding, or clipping +1 to 255/128 − 1): |Δq| ≤ 2/128,
    # angle ≤ 2·|Δq| = 1/32 rad
    assert quat_angle(back.rotations, cloud.rotations).max() <= 1 / 32


# ------------------------------------------------------------------ Niantic .spz
def plain_spz_v2(points: list[dict], frac: int = 12, version: int = 2) -> bytes:
    """A version-2 (or 1: float16 positions) .spz packed by hand from the spec (RUB axes: y, z negated)."""
    out = [struct.pack("<IIIBBBB", 0x5053474E, version, len(points), 0, frac, 0, 0)]
    for p in points:
        for v in (p["xyz"][0], -p["xyz"][1], -p["xyz"][2]):
            out.append(struct.pack("<e", v) if version == 1 else struct.pack("<i", round(v * (1 << frac)))[:3])
    out += [bytes([round(p["alpha"] * 255)]) for p in points]
    out += [bytes(round(c * 0.15 * 255 + 127.5) for c in p["f_dc"]) for p in points]
    out += [bytes(round((s + 10) * 16) for s in p["log_scale"]) for p in points]
    for p in points:
        w, x, y, z = p["wxyz"]
        x, y, z = x, -y, -z  # quaternion in RUB
        s = 1 if w >= 0 else -1
        out.append(bytes(round(c * s * 127.5 + 127.5) for c in (x, y, z)))
    return gzip_bytes(b"".join(out))


def gzip_bytes(data: bytes) -> bytes:
    import gzip

    return gzip.compress(data)


SPZ_POINTS = [
    {"xyz": (0.25, -1.5, 2.0), "alpha": 0.8, "f_dc": (0.0, 1.0, -1.0), "log_scale": (-4.0, -3.5, -6.0),
     "wxyz": (1.0, 0.0, 0.0, 0.0)},
    {"xyz": (-3.0, 0.125, 0.0), "alpha": 0.2, "f_dc": (2.0, -2.0, 0.5), "log_scale": (-2.0, -2.0, -2.0),
     "wxyz": (math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))},
]


def check_spz_points(cloud: SplatCloud) -> None:
    np.testing.assert_allclose(cloud.means, [p["xyz"] for p in SPZ_POINTS], atol=0.5 / 4096 + 1e-7)
    np.testing.assert_allclose(cloud.opacities, [p["alpha"] for p in SPZ_POINTS], atol=0.5 / 255)
    np.testing.assert_allclose(cloud.sh_dc, [p["f_dc"] for p in SPZ_POINTS], atol=0.5 / (255 * 0.15) + 1e-6)
    np.testing.assert_allclose(cloud.log_scales, [p["log_scale"] for p in SPZ_POINTS], atol=0.5 / 16)
    # v2 bytes c/127.5 − 1 cannot hold 0 (off by 0.5/127.5 per component): angle ≤ 2·√3·0.5/127.5 ≈ 0.0136
    assert quat_angle(cloud.rotations, np.array([p["wxyz"] for p in SPZ_POINTS])).max() < 0.014


@pytest.mark.parametrize("version", [1, 2])
def test_spz_v1_v2_written_from_the_spec_read_back(tmp_path: Path, version: int) -> None:
    (tmp_path / "hand.spz").write_bytes(plain_spz_v2(SPZ_POINTS, version=version))
    cloud = read_splat(tmp_path / "hand.spz")
    assert cloud.source_format == "spz" and len(cloud) == 2
    check_spz_points(cloud)


def test_spz_v4_zstd_streams_read(tmp_path: Path) -> None:
    """A version-4 file built from the spec: 32-byte header, TOC, one ZSTD frame per attribute."""
    zstd = pytest.importorskip("zstandard")
    import gzip

    legacy = gzip.decompress(plain_spz_v2(SPZ_POINTS))[16:]
    n = len(SPZ_POINTS)
    sizes = [9 * n, n, 3 * n, 3 * n, 3 * n]  # positions, alphas, colours, scales, rotations (v2 layout)
    parts, off = [], 0
    for size in sizes:
        parts.append(legacy[off: off + size])
        off += size
    # version 4 stores smallest-three rotations: re-pack them by hand (w largest → index 3 in x,y,z,w)
    rots = []
    for p in SPZ_POINTS:
        w, x, y, z = p["wxyz"]
        q = [x, -y, -z, w]  # RUB, x,y,z,w order
        big = max(range(4), key=lambda i: abs(q[i]))
        if q[big] < 0:
            q = [-c for c in q]
        comp = big
        for i in range(4):
            if i != big:
                comp = (comp << 10) | ((1 << 9) if q[i] < 0 else 0) | round(511 * abs(q[i]) / math.sqrt(0.5))
        rots.append(struct.pack("<I", comp))
    parts[4] = b"".join(rots)
    frames = [zstd.ZstdCompressor().compress(p) for p in parts]
    header = struct.pack("<IIIBBBBI12x", 0x5053474E, 4, n, 0, 12, 0, len(frames), 32)
    toc = b"".join(struct.pack("<QQ", len(f), len(p)) for f, p in zip(frames, parts))
    (tmp_path / "v4.spz").write_bytes(header + toc + b"".join(frames))
    assert detect_format(tmp_path / "v4.spz") == "spz"
    check_spz_points(read_splat(tmp_path / "v4.spz"))


@pytest.mark.parametrize("version", [2, 3])
def test_spz_round_trip_within_quantisation(tmp_path: Path, version: int) -> None:
    from pixie_gs.formats import spz

    cloud = random_cloud(1000, rest=24, extras=True)
    spz.write(cloud, tmp_path / "r.spz", version=version)
    back = read_splat(tmp_path / "r.spz")
    assert back.sh_degree == 2 and not back.extras
    assert np.abs(back.means - cloud.means).max() <= 0.5 / 4096 + 1e-6  # 24-bit fixed point, 12 fraction bits
    assert np.abs(back.opacities - cloud.opacities).max() <= 0.5 / 255 + 1e-6
    assert np.abs(back.sh_dc - cloud.sh_dc).max() <= 0.5 / (255 * 0.15) + 1e-5  # f_dc·0.15·255 + 127.5 in u8
    assert np.abs(back.log_scales - cloud.log_scales).max() <= 0.5 / 16 + 1e-5  # (log σ + 10)·16 in u8
    assert np.abs(back.sh_rest - cloud.sh_rest).max() <= 0.5 / 128 + 1e-6  # sh·128 + 128 in u8
    # v3: 9-bit magnitudes of step √½/511 → angle ≤ 4·√3·ε, ε = √½/1022. v2: x,y,z off by ≤ 0.5/127.5
    # each (|Δ| ≤ Δ = √3·0.5/127.5) and w = √(1 − |xyz|²) by ≤ √(2Δ + Δ²) (large near w ≈ 0), so the
    # angle ≤ 2·√(Δ² + 2Δ + Δ²) ≈ 0.24 rad — why pixie-gs writes version 3
    if version == 3:
        bound = 4 * math.sqrt(3) * math.sqrt(0.5) / 1022 + 1e-4
    else:
        d = math.sqrt(3) * 0.5 / 127.5
        bound = 2 * math.sqrt(2 * d * d + 2 * d) + 1e-3
    assert quat_angle(back.rotations, cloud.rotations).max() <= bound


# ------------------------------------------------------------------ exports of gsplat / nerfstudio
def test_gsplat_and_nerfstudio_style_plys_read(tmp_path: Path) -> None:
    """gsplat's export (no normals, f_dc before f_rest), nerfstudio's (normals, unnormalised quats),
    a float64 export with shuffled property order and an extra per-Gaussian property."""
    rng = np.random.default_rng(5)
    n = 64
    cols = {"x": rng.normal(size=n), "y": rng.normal(size=n), "z": rng.normal(size=n)}
    cols.update({f"f_dc_{i}": rng.normal(size=n) for i in range(3)})
    cols.update({f"f_rest_{i}": rng.normal(size=n) * 0.1 for i in range(9)})
    cols["opacity"] = rng.normal(size=n)
    cols.update({f"scale_{i}": rng.uniform(-6, -2, n) for i in range(3)})
    cols.update({f"rot_{i}": rng.normal(size=n) * 3 for i in range(4)})
    gsplat_order = list(cols)
    nerfstudio_order = ["x", "y", "z", "nx", "ny", "nz"] + gsplat_order[3:]
    shuffled = list(reversed(gsplat_order)) + ["segment_id"]
    cols.update({"nx": np.zeros(n), "ny": np.zeros(n), "nz": np.zeros(n), "segment_id": rng.integers(0, 9, n)})
    for name, order, ftype in [("gsplat", gsplat_order, "<f4"), ("nerfstudio", nerfstudio_order, "<f4"),
                               ("float64", shuffled, "<f8")]:
        dtype = [(k, "<i4" if k == "segment_id" else ftype) for k in order]
        table = np.empty(n, dtype=dtype)
        for k in order:
            table[k] = cols[k]
        PlyData([PlyElement.describe(table, "vertex")]).write(str(tmp_path / f"{name}.ply"))
        cloud = read_splat(tmp_path / f"{name}.ply")
        assert cloud.source_format == "inria_ply" and cloud.sh_degree == 1, name
        np.testing.assert_allclose(cloud.means[:, 1], cols["y"], rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(cloud.sh_rest[:, 8], cols["f_rest_8"], rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(cloud.rotations[:, 3], cols["rot_3"], rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(read_splat(tmp_path / "float64.ply").extras["segment_id"], cols["segment_id"])


def test_gsplat_compressed_ply_with_empty_sh_element_reads(tmp_path: Path) -> None:
    """gsplat's compressed export always declares `element sh N`, with no properties at SH degree 0."""
    raw = GUITAR.read_bytes()
    raw = raw.replace(b"end_header\n", b"element sh 768\nend_header\n", 1)
    (tmp_path / "gs.ply").write_bytes(raw)
    cloud = read_splat(tmp_path / "gs.ply")
    assert cloud.sh_degree == 0
    np.testing.assert_array_equal(cloud.means, read_splat(GUITAR).means)


def test_info_reports_the_format_found_by_content(tmp_path: Path) -> None:
    import json

    shutil.copy(GUITAR, tmp_path / "capture.ply")  # a compressed PLY under a plain .ply name
    proc = subprocess.run([sys.executable, "-m", "pixie_gs", "info", str(tmp_path / "capture.ply"), "--json"],
                          capture_output=True, text=True, check=True)
    info = json.loads(proc.stdout.strip().splitlines()[-1])
    assert info["format"] == "compressed_ply" and info["count"] == 768
    proc = subprocess.run([sys.executable, "-m", "pixie_gs", "info", str(tmp_path / "capture.ply")],
                          capture_output=True, text=True, check=True)
    assert "SuperSplat compressed PLY" in proc.stdout
