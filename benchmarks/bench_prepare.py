"""Scene preparation figures: up error on generated objects under random rotations, up and object
box on the real assets in ../shared/real, and prepare time on a 1,000,000-Gaussian capture with
the time to read that file as the same-run baseline.

usage: python benchmarks/bench_prepare.py [--objects 100] [--real ../shared/real] [--skip-speed]
Real meshes are converted first with `pixie convert MESH OUT.ply` (defaults), as expectations.json says.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def generated_up_errors(count: int) -> list[tuple[str, float, str]]:
    from scipy.spatial.transform import Rotation

    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.prepare import prepare_cloud
    from pixie_gs.prepare.updir import angle_deg

    table = load_class_table()
    names = sorted(table)
    out = []
    for i in range(count):
        name = names[i % len(names)]
        cloud, _ = build_object(table[name], object_seed(11, "test", i), 20000)
        R = Rotation.random(random_state=i).as_matrix()
        cloud.means = (cloud.means.astype(np.float64) @ R.T).astype(np.float32)
        cloud.set_covariances(R @ cloud.covariances() @ R.T)
        _, scene = prepare_cloud(cloud)
        out.append((name, angle_deg(scene.up, R @ [0, 0, 1]), scene.up_method))
    return out


def real_assets(real: Path, work: Path) -> list[dict]:
    from pixie_gs.prepare import prepare_cloud
    from pixie_gs.prepare.updir import angle_deg
    from pixie_gs.splat import read_splat

    entries = json.loads((real / "expectations.json").read_text())
    rows = []
    for e in entries:
        stem = Path(e["file"]).stem
        mesh = real / "orig" / f"{stem}.glb"
        if mesh.exists():
            path = work / e["file"]
            if not path.exists():
                subprocess.run([sys.executable, "-m", "pixie_gs", "convert", "-q", str(mesh), str(path)], check=True)
        else:
            cands = [real / "orig" / e["file"], real / "orig" / f"{stem}.compressed.ply"]
            path = next(p for p in cands if p.exists())
        cloud = read_splat(path)
        _, scene = prepare_cloud(cloud)
        box = np.asarray(scene.objects[0].box_file) if scene.objects else None
        exp = np.asarray(e["object_box"])
        size = float((exp[1] - exp[0]).max())
        rows.append({"file": e["file"], "up_error_deg": angle_deg(scene.up, e["up"]), "method": scene.up_method,
                     "confidence": scene.up_confidence,
                     "box_error_of_size": None if box is None else float(np.abs(box - exp).max() / size),
                     "counts": scene.counts, "seconds": scene.seconds})
    return rows


def speed(real: Path, work: Path) -> tuple[float, float, int]:
    from pixie_gs.prepare import prepare_cloud
    from pixie_gs.splat import SplatCloud, read_splat, write_splat

    base = read_splat(real / "orig" / "donut_fused.ply")
    reps = int(np.ceil(1_000_000 / len(base)))
    rng = np.random.default_rng(0)
    parts = []
    for k in range(reps):
        c = base.copy()
        c.means = (c.means + rng.normal(0, 5e-4, c.means.shape)).astype(np.float32)
        parts.append(c)
    big = SplatCloud.concatenate(parts).subset(np.arange(1_000_000))
    path = work / "big.ply"
    write_splat(big, path)
    t = time.perf_counter()
    cloud = read_splat(path)
    read_s = time.perf_counter() - t
    t = time.perf_counter()
    prepare_cloud(cloud)
    prep_s = time.perf_counter() - t
    return prep_s, read_s, len(cloud)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--objects", type=int, default=100)
    ap.add_argument("--real", default="../shared/real")
    ap.add_argument("--skip-speed", action="store_true")
    args = ap.parse_args()
    real = Path(args.real)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if not args.skip_speed and real.exists():
            prep_s, read_s, n = speed(real, work)
            print(f"speed: prepare {n} Gaussians {prep_s:.2f} s; read the same file {read_s:.2f} s "
                  f"(ratio {prep_s / read_s:.2f}); target ≤ 3 s")
        if real.exists():
            for row in real_assets(real, work):
                print(f"real {row['file']:16s} up error {row['up_error_deg']:6.1f}° ({row['method']}, "
                      f"confidence {row['confidence']:.2f}); object box error {row['box_error_of_size']} of its size; "
                      f"{row['seconds']:.2f} s")
    if args.objects:
        errs = generated_up_errors(args.objects)
        e = np.array([v for _, v, _ in errs])
        print(f"generated: {len(e)} objects, up error median {np.median(e):.1f}°, worst {e.max():.1f}°, "
              f"≤ 20° on {np.mean(e <= 20) * 100:.0f} %")
        for name in sorted({n for n, _, _ in errs}):
            v = np.array([x for n, x, _ in errs if n == name])
            print(f"  {name:18s} median {np.median(v):6.1f}°  worst {v.max():6.1f}°")
    return 0


if __name__ == "__main__":
    sys.exit(main())
