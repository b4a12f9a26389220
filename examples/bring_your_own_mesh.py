"""Bring your own mesh: a triangle mesh (any file trimesh loads: .glb .gltf .obj .ply .stl, or by
default a built-in orange ball made with trimesh) → `pixie convert`'s sampler → predicted
materials → dropped on the ground with the `drop` preset.

    python examples/bring_your_own_mesh.py --out examples_out/bring_your_own_mesh
    python examples/bring_your_own_mesh.py --mesh my_toy.glb --up y --out examples_out/my_toy
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402

FULL = _common.Size(frames=30, fps=30.0, grid=48, particles_per_cell=2)
TINY = _common.Size(frames=12, fps=30.0, grid=24, particles_per_cell=2)
FULL_GAUSSIANS, TINY_GAUSSIANS = 20_000, 4_000


def default_mesh():
    """An orange ball of radius 0.1 with a white band (a stand-in for your mesh), vertex-coloured."""
    import numpy as np
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    stripe = np.abs(ball.vertices[:, 2]) < 0.015  # a white band around the equator, like a toy ball
    colours = np.where(stripe[:, None], [240, 240, 235, 255], [240, 120, 30, 255])
    ball.visual.vertex_colors = colours.astype(np.uint8)
    return ball


def main(argv: list[str] | None = None) -> dict:
    import numpy as np

    from pixie_gs.annotate import annotate_cloud
    from pixie_gs.convert import load_mesh, mesh_to_splat
    from pixie_gs.demo import material_summary
    from pixie_gs.progress import stage
    from pixie_gs.sim.scene import Scene

    p = _common.parser(__doc__, "bring_your_own_mesh")
    p.add_argument("--mesh", default=None, help="mesh file (default: a built-in ball made with trimesh)")
    p.add_argument("--up", default="z", help="axis of the mesh that points up: z, y, -y, ... (default z)")
    args = p.parse_args(argv)
    if args.labels == "true":
        p.error("--labels true needs a generated object; a mesh has no ground-truth materials")
    mesh = load_mesh(args.mesh) if args.mesh else default_mesh()  # a bad mesh stops before any output
    out = _common.setup(args)
    count = TINY_GAUSSIANS if args.tiny else FULL_GAUSSIANS
    splat = mesh_to_splat(mesh, count, np.random.default_rng(args.seed), fill=bool(mesh.is_watertight),
                          n_fill=count // 2)
    splat.write(out / "converted.ply")
    stage(f"converted {'the built-in ball' if args.mesh is None else args.mesh} to {len(splat)} Gaussians")
    cloud = annotate_cloud(splat, checkpoint=args.checkpoint, device=args.device, up=args.up)
    cloud.write(out / "annotated.ply")
    stage("predicted " + ", ".join(f"{k} {v}" for k, v in material_summary(cloud).items()))
    scene = Scene.preset("drop").to_dict()
    scene["up"] = args.up
    scene["domain"]["size_m"] = 1.2
    scene["solver"]["max_substeps_per_frame"] = 200  # bounds the run time whatever stiffness is predicted
    result = _common.simulate(cloud, scene, TINY if args.tiny else FULL, args, out, "bring_your_own_mesh")
    centre = result.x_world[:, :, 2].mean(axis=1)
    return _common.report("bring_your_own_mesh", out, result, {
        "converted_gaussians": len(splat),
        "materials": material_summary(cloud),
        "centre_height_start_m": float(centre[0]),
        "centre_height_end_m": float(centre[-1]),
        "fell": bool(centre[-1] < centre[0] - 0.05),
    })


if __name__ == "__main__":
    _common.run_cli(main)
