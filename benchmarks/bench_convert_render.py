"""Speed of mesh → splat conversion and of the point-splat renderer, with same-run baselines.

convert: pixie_gs.convert.mesh_to_splat (positions, tangent frames, texture colours, write-ready
cloud) vs trimesh.sample.sample_surface (positions only) on a textured sphere of 20,480 triangles.
render: pixie_gs.render.render_points (z-buffered discs) vs a matplotlib Agg scatter of the same
points at the same size. Writes a contact sheet of the converted sphere to --picture.

usage: python benchmarks/bench_convert_render.py [--count 50000] [--points 100000] [--picture out.png]
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def best_of(fn, repeats: int = 5) -> float:
    """Smallest wall time (s) of `repeats` calls (the machine is shared; the minimum is the signal)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def textured_sphere():
    """Icosphere with a spherical UV map and a 512² checker-and-gradient texture."""
    import trimesh
    from PIL import Image

    sphere = trimesh.creation.icosphere(subdivisions=5)
    v = sphere.vertices
    longitude = 0.5 + np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi)
    latitude = 0.5 + np.arcsin(np.clip(v[:, 2], -1, 1)) / np.pi
    uv = np.stack([longitude, latitude], axis=1)
    yy, xx = np.mgrid[:512, :512]
    checker = ((xx // 64 + yy // 64) % 2).astype(np.float64)
    texture = np.stack([xx / 511, checker, yy / 511], axis=2)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray((texture * 255).astype(np.uint8)))
    sphere.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return sphere


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=50_000, help="surface Gaussians to sample")
    parser.add_argument("--points", type=int, default=100_000, help="points to render")
    parser.add_argument("--picture", default=None, help="contact sheet PNG of the converted sphere")
    args = parser.parse_args()

    import matplotlib
    import trimesh

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pixie_gs.convert import mesh_to_splat
    from pixie_gs.progress import set_quiet
    from pixie_gs.render import contact_sheet, render_points, save_png

    set_quiet(True)
    sphere = textured_sphere()
    t_ours = best_of(lambda: mesh_to_splat(sphere, args.count, np.random.default_rng(0)), repeats=15)
    t_base = best_of(lambda: trimesh.sample.sample_surface(sphere, args.count, seed=0), repeats=15)
    print(f"convert  {args.count} Gaussians from {len(sphere.faces)} textured triangles: "
          f"{t_ours * 1e3:.1f} ms  (trimesh.sample_surface positions only: {t_base * 1e3:.1f} ms, "
          f"ratio {t_ours / t_base:.2f}x)")
    t_fill = best_of(lambda: mesh_to_splat(sphere, args.count, np.random.default_rng(0), fill=True), repeats=2)
    print(f"convert  --fill: {args.count} surface + {args.count} interior Gaussians: {t_fill * 1e3:.1f} ms")

    cloud = mesh_to_splat(sphere, args.points, np.random.default_rng(1))
    means, rgb = cloud.means, cloud.rgb()
    render_points(means[:10], rgb[:10])  # warm-up
    t_render = best_of(lambda: render_points(means, rgb, size=(256, 256)), repeats=10)

    def matplotlib_scatter():
        fig = plt.figure(figsize=(2.56, 2.56), dpi=100)
        ax = fig.add_subplot(projection="3d")
        ax.scatter(means[:, 0], means[:, 1], means[:, 2], c=rgb, s=1, depthshade=False)
        ax.view_init(elev=20, azim=30)
        fig.canvas.draw()
        np.asarray(fig.canvas.buffer_rgba())
        plt.close(fig)

    t_mpl = best_of(matplotlib_scatter, repeats=3)
    print(f"render   {args.points} points at 256x256: {t_render * 1e3:.1f} ms  "
          f"(matplotlib 3D scatter, same points: {t_mpl * 1e3:.1f} ms, ratio {t_render / t_mpl:.2f}x)")

    if args.picture:
        views = [render_points(means, rgb, azimuth_deg=az, elevation_deg=20) for az in (0, 90, 180, 270)]
        save_png(contact_sheet(views, [f"azimuth {az}" for az in (0, 90, 180, 270)], columns=4), args.picture)
        print(f"picture  {args.picture}")


if __name__ == "__main__":
    main()
