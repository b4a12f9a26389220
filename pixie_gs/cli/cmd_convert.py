"""`pixie convert MESH OUT.ply`: a triangle mesh (.glb/.gltf/.obj/.ply/.stl) to a 3DGS splat."""
from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "convert", parents=parents, help="turn a mesh into a 3D Gaussian splat .ply",
        description="Sample a triangle mesh into flat surface Gaussians coloured from its texture, "
        "vertex or face colours (and, with --fill, isotropic Gaussians inside a closed mesh). "
        "Scenes are flattened with their transforms; the same --seed gives identical bytes.",
        epilog="example: pixie convert duck.glb duck.ply --count 200000 --fill --seed 1",
    )
    p.add_argument("mesh", metavar="MESH", help="mesh file: .glb .gltf .obj .ply .stl .off")
    p.add_argument("out", metavar="OUT.ply", help="splat file to write (binary little-endian 3DGS)")
    p.add_argument("--count", type=int, default=100_000, help="surface Gaussians (default 100000)")
    p.add_argument("--fill", action="store_true", help="also fill the inside of a watertight mesh")
    p.add_argument("--fill-count", type=int, default=None,
                   help="interior Gaussians with --fill (default: same as --count)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file")
    p.add_argument("--preview", metavar="PNG", default=None,
                   help="also write a PNG with four views of the splat (point-splat render; +y up "
                   "for glTF/OBJ input, whose convention it is, +z up otherwise)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from ..atomic import check_distinct_output
    from ..convert import load_mesh, mesh_to_splat
    from ..errors import InputError
    from ..progress import stage
    from ..splat import write_splat

    if args.count < 1:
        raise InputError(f"--count must be ≥ 1 (got {args.count})")
    if args.fill_count is not None and args.fill_count < 0:
        raise InputError(f"--fill-count must be ≥ 0 (got {args.fill_count})")
    for target in [args.out] + ([args.preview] if args.preview else []):
        if not Path(target).parent.is_dir():
            raise InputError("output directory does not exist", Path(target).parent)
    check_distinct_output(args.mesh, args.out, args.force)
    mesh = load_mesh(args.mesh)
    stage(f"read {len(mesh.faces)} triangles from {args.mesh}; sampling {args.count} surface Gaussians"
          + (" and filling the interior" if args.fill else ""))
    cloud = mesh_to_splat(mesh, args.count, np.random.default_rng(args.seed), fill=args.fill,
                          n_fill=args.fill_count)
    write_splat(cloud, args.out)
    stage(f"wrote {len(cloud)} Gaussians to {args.out}")
    if args.preview:
        up = "y" if Path(args.mesh).suffix.lower() in (".glb", ".gltf", ".obj") else "z"
        write_preview(cloud, args.preview, up)
        stage(f"wrote preview {args.preview}")
    return 0


def write_preview(cloud, png: str, up: str = "z") -> None:
    """Four views (azimuth 0/90/180/270°, elevation 20°) of the splat's colours in one PNG."""
    from ..render import contact_sheet, render_points, save_png

    bounds = cloud.bounds()
    azimuths = (0, 90, 180, 270)
    views = [render_points(cloud.means, cloud.rgb(), azimuth_deg=az, up=up, bounds=bounds) for az in azimuths]
    save_png(contact_sheet(views, [f"azimuth {az} deg" for az in azimuths], columns=4), png)
