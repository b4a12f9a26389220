"""Splat formats on real captures and at 1M Gaussians: detection, extents, round-trip errors, speed.

    python benchmarks/bench_formats.py                      # real captures in ../shared/real/orig
    python benchmarks/bench_formats.py --pair A.spz B.compressed.ply   # same scene in two formats
    python benchmarks/bench_formats.py --count 1000000 --skip-real     # speed only

Real part: every splat in ../shared/real/orig (meshes skipped, missing files skipped): count,
format found by content, read time, the capture's 1–99 % extent and how much of the object box in
../shared/real/expectations.json it covers, then PLY → each format → back with the largest errors
(position, log-scale, rgb, opacity, rotation angle). `--pair` decodes two files written by other
tools from one capture and matches them Gaussian to Gaussian (nearest centre).
Speed part: a random SH-degree-3 cloud of `--count` Gaussians written and read in every format;
baseline in the same run: the INRIA file's raw bytes read with numpy.fromfile and written with
ndarray.tofile (no parsing, no validation).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "real"
sys.path.insert(0, str(ROOT))

from pixie_gs.errors import InputError  # noqa: E402
from pixie_gs.formats import FORMATS, LABELS, detect_format, read_any, write_any  # noqa: E402
from pixie_gs.splat import SplatCloud  # noqa: E402

SUFFIX = {"inria_ply": ".ply", "compressed_ply": ".compressed.ply", "splat": ".splat", "spz": ".spz"}


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def quat_angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=1)), 0, 1)))


SPZ_LOG_SCALE_RANGE = (-10.0, 255 / 16 - 10.0)  # what .spz's u8 (log σ + 10)·16 can hold


def errors(ref: SplatCloud, got: SplatCloud, fmt: str) -> dict:
    """Largest differences between two clouds of the same Gaussians in the same order (.spz: log-scale
    error over the Gaussians inside its range, and how many lie outside and were clamped)."""
    inside = np.ones(len(ref), bool)
    out = {}
    if fmt == "spz":
        lo, hi = SPZ_LOG_SCALE_RANGE
        inside = ((ref.log_scales >= lo) & (ref.log_scales <= hi)).all(axis=1)
        out["clamped"] = int((~inside).sum())
    if fmt == "compressed_ply":  # 11/10/11 bits over each 256-Gaussian chunk's range (file order kept)
        n_chunks = -(-len(ref) // 256)
        pad = np.concatenate([ref.means, np.repeat(ref.means[-1:], n_chunks * 256 - len(ref), axis=0)])
        span = (pad.reshape(n_chunks, 256, 3).max(axis=1) - pad.reshape(n_chunks, 256, 3).min(axis=1))
        bound = np.repeat(span, 256, axis=0)[: len(ref)] / (2 * np.array([2047.0, 1023.0, 2047.0])) + 1e-6
        out["pos_in_bound"] = "yes" if (np.abs(got.means - ref.means) <= bound).all() else "NO"
    return out | {
        "pos_m": float(np.abs(got.means - ref.means).max()),
        "log_scale": float(np.abs(got.log_scales - ref.log_scales)[inside].max()),
        "rgb": float(np.abs(got.rgb() - ref.rgb()).max()),
        "opacity": float(np.abs(got.opacities - ref.opacities).max()),
        "rot_deg": float(quat_angle_deg(got.rotations.astype(np.float64), ref.rotations.astype(np.float64)).max()),
    }


def round_trip(cloud: SplatCloud, fmt: str, tmp: Path) -> tuple[dict, float, float]:
    """Write `cloud` as `fmt` (file order kept) and read it back: errors, write s, read s."""
    path = tmp / f"rt{SUFFIX[fmt]}"
    if fmt == "compressed_ply":
        from pixie_gs.formats import compressed_ply

        _, t_write = timed(compressed_ply.write, cloud, path, keep_order=True)
    else:
        _, t_write = timed(write_any, cloud, path, fmt)
    back, t_read = timed(read_any, path)
    return errors(cloud, back, fmt), t_write, t_read


def box_coverage(lo: np.ndarray, hi: np.ndarray, box: list) -> float:
    """Share of the expected object box's volume inside [lo, hi]."""
    b_lo, b_hi = np.array(box[0]), np.array(box[1])
    inter = np.clip(np.minimum(hi, b_hi) - np.maximum(lo, b_lo), 0, None)
    return float(np.prod(inter) / np.prod(b_hi - b_lo))


def real_captures(files: list[Path]) -> None:
    expectations = {}
    if (REAL / "expectations.json").exists():
        expectations = {e["file"]: e for e in json.loads((REAL / "expectations.json").read_text())}
    print("== real captures (format found by content; extents 1-99 %; round trips in file order) ==")
    for path in files:
        if not path.exists():
            print(f"{path.name}: missing, skipped")
            continue
        try:
            fmt = detect_format(path)
        except InputError as exc:
            print(f"{path.name}: not a splat ({str(exc).split(': ', 1)[-1]}), skipped")
            continue
        cloud, t_read = timed(read_any, path)
        lo = np.percentile(cloud.means.astype(np.float64), 1, axis=0)
        hi = np.percentile(cloud.means.astype(np.float64), 99, axis=0)
        key = path.name.replace(".compressed.ply", ".ply")
        line = (f"{path.name}: {len(cloud)} Gaussians, {LABELS[fmt]}, SH {cloud.sh_degree}, read {t_read:.2f} s; "
                f"extent {[round(v, 2) for v in lo.tolist()]} .. {[round(v, 2) for v in hi.tolist()]} m")
        if key in expectations:
            box = expectations[key]["object_box"]
            full = box_coverage(cloud.means.min(axis=0).astype(np.float64), cloud.means.max(axis=0).astype(np.float64),
                                box)
            line += (f"; object box {box}: {100 * box_coverage(lo, hi, box):.0f} % inside the 1-99 % extent, "
                     f"{100 * full:.0f} % inside min-max")
        print(line)
        with tempfile.TemporaryDirectory() as tmp:
            for target in FORMATS:
                err, t_w, t_r = round_trip(cloud, target, Path(tmp))
                print(f"    -> {target:<14} write {t_w:5.2f} s  read {t_r:5.2f} s  max err: "
                      + "  ".join(f"{k} {v}" if isinstance(v, (int, str)) else f"{k} {v:.3g}" for k, v in err.items()))
        print(f"    compressed-PLY and spz errors are within each format's quantisation (see docs/user_guide.md "
              "Formats); spz 'clamped' counts Gaussians with log σ outside [-10, 5.94]")


def pair(a_path: Path, b_path: Path) -> None:
    from scipy.spatial import cKDTree

    a, b = read_any(a_path), read_any(b_path)
    dist, idx = cKDTree(b.means).query(a.means)
    same = float(np.mean(idx == np.arange(len(a)))) if len(a) == len(b) else float("nan")
    print(f"== same capture, two files by other tools: {a_path.name} ({LABELS[a.source_format]}, {len(a)}) vs "
          f"{b_path.name} ({LABELS[b.source_format]}, {len(b)}) ==")
    print(f"    nearest centre: median {np.median(dist) * 1000:.3f} mm, 99 % {np.percentile(dist, 99) * 1000:.3f} mm; "
          f"same index for {100 * same:.1f} %")
    print(f"    matched: opacity |diff| median {np.median(np.abs(a.opacities - b.opacities[idx])):.4f}, "
          f"rgb median {np.median(np.abs(a.rgb() - b.rgb()[idx])):.4f}, log-scale median "
          f"{np.median(np.abs(a.log_scales - b.log_scales[idx])):.4f}, rotation median "
          f"{np.median(quat_angle_deg(a.quats, b.quats[idx])):.3f} deg")


def speed(count: int) -> None:
    rng = np.random.default_rng(0)
    cloud = SplatCloud.from_arrays(
        rng.uniform(-2, 2, (count, 3)), log_scales=rng.uniform(-7, -2, (count, 3)),
        rotations=rng.normal(size=(count, 4)), opacity_logits=rng.uniform(-5, 5, count),
        rgb=rng.uniform(0, 1, (count, 3)), sh_rest=rng.uniform(-0.5, 0.5, (count, 45)))
    print(f"== speed: {count} Gaussians, SH degree 3 (seconds; x = time / baseline) ==")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_any(cloud, tmp / "base.ply", "inria_ply")
        raw = np.fromfile(tmp / "base.ply", np.uint8)
        _, base_read = timed(np.fromfile, tmp / "base.ply", np.uint8)
        _, base_write = timed(raw.tofile, tmp / "raw.bin")
        _, t_validate = timed(cloud.validate)
        print(f"baseline (raw bytes of the {raw.nbytes / 1e6:.0f} MB INRIA file): read {base_read:.2f} s, "
              f"write {base_write:.2f} s; every read and write below includes SplatCloud.validate: "
              f"{t_validate:.2f} s on this cloud")
        for fmt in FORMATS:
            path = tmp / f"s{SUFFIX[fmt]}"
            _, t_w = timed(write_any, cloud, path, fmt)
            _, t_r = timed(read_any, path)
            size = path.stat().st_size
            print(f"{fmt:<14} write {t_w:6.2f} s ({t_w / base_write:5.1f}x)  read {t_r:6.2f} s "
                  f"({t_r / base_read:5.1f}x)  {size / 1e6:7.1f} MB ({size / len(cloud):.1f} B/Gaussian)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=1_000_000, help="Gaussians in the speed test")
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--pair", nargs=2, metavar="FILE", help="two files of one capture in different formats")
    ap.add_argument("files", nargs="*", help="captures to check (default: every file in ../shared/real/orig)")
    args = ap.parse_args()
    if not args.skip_real:
        files = [Path(f) for f in args.files] or sorted((REAL / "orig").glob("*"))
        real_captures(files)
    if args.pair:
        pair(Path(args.pair[0]), Path(args.pair[1]))
    if not args.skip_speed:
        speed(args.count)


if __name__ == "__main__":
    main()
