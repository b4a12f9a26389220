"""Speed and accuracy of the real 3DGS renderer (pixie_gs.gsrender), with same-run baselines.

Scene: N Gaussians (default 100,000) on a bumpy sphere shell, anisotropic, randomly rotated, SH
degree 3 (or --ply FILE, any splat), seen by the orbit camera at SIZE² (default 512²).
Measured: the full frame (projection, SH colour, tile sort, compositing; best of --repeats, after
one warm-up call that also compiles the Warp kernel) for the Warp and the torch compositing
backends; baselines in the same run: the old point renderer (pixie_gs.render.render_points) on the
same centres and size, and the brute-force per-pixel reference on a small image, whose cost per
pixel × Gaussian is extrapolated to the full frame. Accuracy: fast vs reference on that small image.

usage: python benchmarks/bench_render.py [--count 100000] [--size 512] [--device cpu|cuda] [--ply FILE]
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def shell_scene(n: int, seed: int = 0):
    """A SplatCloud of n Gaussians on a unit sphere shell, sized to close the surface."""
    from pixie_gs.splat import SplatCloud

    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    means = d * (1 + 0.05 * np.sin(6 * d[:, :1]) + 0.01 * rng.normal(size=(n, 1)))
    spacing = np.sqrt(4 * np.pi / n)
    q = rng.normal(size=(n, 4))
    cloud = SplatCloud.from_arrays(
        means, log_scales=np.log(spacing * np.exp(rng.normal(scale=0.4, size=(n, 3)))).astype(np.float32),
        rotations=(q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32),
        opacity_logits=rng.normal(1.0, 1.0, n).astype(np.float32),
        sh_dc=((d * 0.5 + 0.5 - 0.5) / 0.2820948).astype(np.float32),
        sh_rest=rng.normal(scale=0.1, size=(n, 45)).astype(np.float32))
    return cloud


CPU_SECONDS: dict[int, float] = {}  # id(fn) -> smallest process CPU time of its calls


def timed(fn, repeats: int, sync=lambda: None) -> float:
    """Smallest wall time (s) of `repeats` calls (shared machine: the minimum is the signal); the
    smallest process CPU time of the calls goes to CPU_SECONDS (what a busy machine does not inflate)."""
    best, best_cpu = float("inf"), float("inf")
    for _ in range(repeats):
        sync()
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        sync()
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    CPU_SECONDS[id(fn)] = best_cpu
    return best


def main() -> None:
    import torch

    from pixie_gs.gsrender import Gaussians, orbit_cameras
    from pixie_gs.gsrender.raster import render
    from pixie_gs.gsrender.reference import reference_render
    from pixie_gs.gsrender.sh import coefficients
    from pixie_gs.render import render_points

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=100_000, help="Gaussians in the synthetic scene")
    parser.add_argument("--size", type=int, default=512, help="image side (px)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--ply", default=None, help="render this splat instead of the synthetic shell")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--ref-size", type=int, default=24, help="side of the brute-force reference image (px)")
    args = parser.parse_args()

    if args.ply:
        from pixie_gs.splat import read_splat

        cloud = read_splat(args.ply)
    else:
        cloud = shell_scene(args.count)
    cam = orbit_cameras(cloud.means, 1, args.size, args.size, up="z")[0]
    g = Gaussians.from_cloud(cloud, args.device)
    sync = torch.cuda.synchronize if args.device.startswith("cuda") else (lambda: None)
    print(f"scene: {len(cloud)} Gaussians (SH degree {cloud.sh_degree}), {args.size}x{args.size} px, "
          f"device {args.device} (torch runs single-threaded inside the renderer on CPU)")

    t0 = time.perf_counter()
    image = render(g, cam)
    sync()
    first = time.perf_counter() - t0
    fast_fn = lambda: render(g, cam)  # noqa: E731
    torch_fn = lambda: render(g, cam, backend="torch")  # noqa: E731
    warp_s = timed(fast_fn, args.repeats, sync)
    torch_s = timed(torch_fn, max(1, args.repeats // 2), sync)
    covered = float((image < 0.98).any(dim=-1).float().mean())
    print(f"gsrender (warp compositing):  {warp_s * 1000:9.1f} ms / frame wall, {CPU_SECONDS[id(fast_fn)] * 1000:.0f} ms "
          f"CPU (first call {first:.2f} s incl. kernel load/compile; {covered:.0%} of pixels covered)")
    print(f"gsrender (torch compositing): {torch_s * 1000:9.1f} ms / frame wall, {CPU_SECONDS[id(torch_fn)] * 1000:.0f} ms CPU")

    if not args.device.startswith("cuda"):
        rgb = cloud.rgb()
        points_fn = lambda: render_points(cloud.means, rgb, size=(args.size, args.size))  # noqa: E731
        points_s = timed(points_fn, args.repeats)
        print(f"baseline point renderer (discs, no blending): {points_s * 1000:9.1f} ms / frame wall, "
              f"{CPU_SECONDS[id(points_fn)] * 1000:.0f} ms CPU (gsrender / points = {warp_s / points_s:.2f} wall)")

    # brute-force reference on a small image around the centre, on a subset of the Gaussians there
    small = cam.resized(args.size, args.size)
    s = args.ref_size
    crop = small.__class__(R=small.R, t=small.t, fx=small.fx, fy=small.fy, cx=small.cx - (args.size - s) / 2,
                           cy=small.cy - (args.size - s) / 2, width=s, height=s, near=small.near)
    p = cloud.means @ np.asarray(crop.R).T + np.asarray(crop.t)
    u = crop.fx * p[:, 0] / p[:, 2] + crop.cx
    v = crop.fy * p[:, 1] / p[:, 2] + crop.cy
    near = np.flatnonzero((u > -8) & (u < s + 8) & (v > -8) & (v < s + 8))
    sub = cloud.subset(near)
    t0 = time.perf_counter()
    ref = reference_render(sub.means, sub.scales, sub.quats, sub.opacities,
                           coefficients(sub.sh_dc, sub.sh_rest), crop)
    ref_s = time.perf_counter() - t0
    fast = render(Gaussians.from_cloud(sub, args.device), crop).cpu().numpy()
    mae = float(np.abs(fast - np.clip(ref, 0, 1)).mean() * 255)
    per_pair = ref_s / (s * s * len(sub))
    est = per_pair * args.size ** 2 * len(cloud)
    print(f"baseline brute-force reference: {ref_s:.2f} s for {s}x{s} px x {len(sub)} Gaussians "
          f"= {per_pair * 1e6:.2f} us per pixel-Gaussian -> ~{est / 3600:.0f} h for the full frame "
          f"(gsrender is ~{est / warp_s:.1e}x faster)")
    print(f"accuracy: gsrender vs reference on that image: mean |error| {mae:.2e} / 255")
    target = 0.020 if args.device.startswith("cuda") else 2.0
    print(f"target {'≤ 20 ms' if target < 1 else '≤ 2 s'} per {args.size}² frame: "
          f"{'met' if warp_s <= target else 'NOT met'} ({warp_s * 1000:.1f} ms wall)")


if __name__ == "__main__":
    main()
