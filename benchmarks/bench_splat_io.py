"""Read + write speed and peak memory of SplatCloud on a large degree-3 3DGS file.

Each measurement runs in a fresh subprocess so its peak RSS is its own. Baseline in the same run:
plain plyfile read (copied out of the memory map) and write of the same file, with no validation
and no SplatCloud columns.

    python benchmarks/bench_splat_io.py --count 1000000
Targets (issue 2): under 5 s each way, peak RSS under 3x the file size.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def make_file(path: Path, count: int) -> None:
    from plyfile import PlyData, PlyElement

    names = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
             + [f"f_rest_{i}" for i in range(45)]
             + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    table = np.empty(count, dtype=[(n, "<f4") for n in names])
    rng = np.random.default_rng(0)
    for n in names:
        table[n] = rng.standard_normal(count, dtype=np.float32)
    PlyData([PlyElement.describe(table, "vertex")]).write(str(path))


def child(mode: str, src: str, dst: str) -> None:
    """One measurement; prints a JSON line with seconds and peak RSS (bytes)."""
    t0 = time.perf_counter()
    if mode == "pixie_read":
        from pixie_gs.splat import read_splat

        cloud = read_splat(src)
        elapsed = time.perf_counter() - t0
    elif mode == "pixie_write":
        from pixie_gs.splat import read_splat

        cloud = read_splat(src)
        t0 = time.perf_counter()
        cloud.write(dst)
        elapsed = time.perf_counter() - t0
    elif mode == "plyfile_read":
        from plyfile import PlyData

        data = np.array(PlyData.read(src)["vertex"].data)  # memory-mapped: copy so every byte is read
        elapsed = time.perf_counter() - t0
    elif mode == "plyfile_write":
        from plyfile import PlyData

        ply = PlyData.read(src)
        t0 = time.perf_counter()
        ply.write(dst)
        elapsed = time.perf_counter() - t0
    else:
        raise SystemExit(f"unknown mode {mode}")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"mode": mode, "seconds": elapsed, "peak_rss": peak}))


def measure(mode: str, src: Path, dst: Path) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", mode, str(src), str(dst)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=1_000_000)
    parser.add_argument("--child", nargs=3, metavar=("MODE", "SRC", "DST"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(*args.child)
        return
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "big.ply", Path(tmp) / "copy.ply"
        make_file(src, args.count)
        size = src.stat().st_size
        print(f"file: {args.count} Gaussians, SH degree 3, {size / 1e6:.1f} MB")
        rows = {m: measure(m, src, dst) for m in ("plyfile_read", "pixie_read", "plyfile_write", "pixie_write")}
        for direction in ("read", "write"):
            ours, base = rows[f"pixie_{direction}"], rows[f"plyfile_{direction}"]
            print(f"{direction:5s}  pixie-gs {ours['seconds']:.2f} s, peak RSS {ours['peak_rss'] / 1e6:.0f} MB "
                  f"({ours['peak_rss'] / size:.2f}x file) | plain plyfile {base['seconds']:.2f} s, "
                  f"{base['peak_rss'] / 1e6:.0f} MB | time ratio {ours['seconds'] / base['seconds']:.2f}")


if __name__ == "__main__":
    main()
