"""`pixie generate OUT_DIR --count N`: a procedural dataset of labelled splats for training."""
from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "generate", parents=parents, help="procedural labelled splats (materials per part) for training",
        description="Write COUNT labelled objects (trees, flowers, shrubs, grass, toys, balls, cans, "
        "crates, sand, snow & mud) as .ply splats with material_id, E, nu, density and part_id per "
        "Gaussian, a .json label record per object and OUT_DIR/SPLIT/index.json. Classes are "
        "balanced (round-robin); the same seed gives identical files for any --workers.",
        epilog="example: pixie generate data --count 200 --workers 2 --preview preview.png",
    )
    p.add_argument("out_dir", metavar="OUT_DIR", help="dataset directory (the split goes in OUT_DIR/SPLIT)")
    p.add_argument("--count", type=int, required=True, help="number of objects")
    p.add_argument("--classes", default=None,
                   help="comma-separated class names (default: every class in the table)")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (default 0)")
    p.add_argument("--split", choices=("train", "val", "test"), default="train",
                   help="split name; mixed into every object's seed (default train)")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (default 1)")
    p.add_argument("--gaussians", type=int, default=50_000,
                   help="Gaussians per object, varied ±20%% per object (default 50000)")
    p.add_argument("--preview", metavar="PNG", default=None,
                   help="also write a contact sheet: up to two objects per class, by RGB and by material")
    p.add_argument("--table", metavar="JSON", default=None,
                   help="class table to use instead of the packaged pixie_gs/data/classes.json")
    p.add_argument("--clean", action="store_true",
                   help="objects exactly as `pixie convert` writes a mesh (one opacity, no texture, noise, "
                        "floaters or tilt) instead of capture-like ones")
    p.add_argument("--pairs", type=float, default=0.0, metavar="SHARE",
                   help="share of objects (0-1) stood beside a partner of another category, footprints "
                        "touching, half the Gaussians each, like two things in one capture (default 0)")
    p.add_argument("--floors", type=float, default=0.0, metavar="SHARE",
                   help="share of objects (0-1) standing on a floor disc labelled stationary, as a capture "
                        "on a table or the ground holds it (default 0)")
    p.add_argument("--leftovers", type=float, default=None, metavar="SHARE",
                   help="share of capture-like objects (0-1) holding interior leftovers: large opaque Gaussians "
                        "inside closed pieces, which no camera of a real capture sees to remove (default 0.3, "
                        "dataset/leftovers.py; none with --clean)")
    p.add_argument("--lighting", type=float, default=None, metavar="SHARE",
                   help="share of capture-like objects (0-1) whose colours carry baked lighting: shade from "
                        "self-occlusion and one sun, glossy highlights (default 0.5, dataset/lighting.py; none "
                        "with --clean)")
    p.add_argument("--force", action="store_true", help="replace an existing split")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..dataset.generate import generate_split
    from ..dataset.leftovers import LEFTOVER_OBJECT_SHARE
    from ..dataset.lighting import LIGHTING_OBJECT_SHARE
    from ..dataset.preview import write_preview
    from ..errors import InputError
    from ..progress import stage

    classes = [c.strip() for c in args.classes.split(",") if c.strip()] if args.classes else None
    if args.preview is not None:
        if not args.preview.lower().endswith(".png"):
            raise InputError("--preview must name a .png file", args.preview)
        if not Path(args.preview).resolve().parent.is_dir():
            raise InputError("--preview: output directory does not exist", Path(args.preview).parent)
    stage(f"generating {args.count} {args.split} objects into {args.out_dir} ({args.workers} workers)")
    split_dir = generate_split(args.out_dir, args.count, classes=classes, seed=args.seed, split=args.split,
                               workers=args.workers, n_gaussians=args.gaussians, table_path=args.table,
                               force=args.force, realistic=not args.clean,
                               pair_share=args.pairs, floor_share=args.floors,
                               leftover_share=LEFTOVER_OBJECT_SHARE if args.leftovers is None else args.leftovers,
                               lighting_share=LIGHTING_OBJECT_SHARE if args.lighting is None else args.lighting)
    stage(f"wrote {split_dir}/index.json")
    if args.preview:
        shown = write_preview(args.out_dir, args.split, args.preview)
        stage(f"preview of {shown} objects: {args.preview}")
    return 0
