"""`pixie prepare IN OUT`: mark floaters, ground, background and objects; estimate up; write the
decisions to OUT.prepare.json. Also the --up/--crop/--no-prepare options annotate and simulate share."""
from __future__ import annotations

import argparse

from ..prepare.updir import add_up_option
from .options import add_drop_invalid_option


def add_prepare_options(p: argparse.ArgumentParser, skip: bool = True) -> None:
    """--up, --crop (and --no-prepare when `skip`) for every command that prepares a capture."""
    add_up_option(p)
    p.add_argument("--crop", default=None, metavar="SPEC",
                   help="the object, in file coordinates: box:x0,y0,z0,x1,y1,z1 | sphere:cx,cy,cz,r | point:x,y,z "
                   "(default: found automatically)")
    if skip:
        p.add_argument("--no-prepare", action="store_true",
                       help="use the file as one clean object (no floater/ground/object detection; --up auto means z)")


def prepare_from_args(cloud, args: argparse.Namespace):
    """(prepared cloud, PreparedScene) — or (cloud, None) with --no-prepare. Prints the summary
    line; the caller writes the sidecar (`write_sidecar`) once its own output is written."""
    from ..prepare import prepare_cloud
    from ..progress import stage

    if getattr(args, "no_prepare", False):
        return cloud, None
    stage(f"preparing {len(cloud)} Gaussians (floaters, up, ground, objects)")
    out, scene = prepare_cloud(cloud, up=args.up, crop=args.crop)
    print(scene.summary(), flush=True)
    return out, scene


def write_sidecar(scene, out_path) -> None:
    """OUT.prepare.json beside `out_path` (nothing when preparation was skipped)."""
    from ..prepare import sidecar_path

    if scene is not None:
        scene.write(sidecar_path(out_path))


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "prepare", parents=parents, help="find up, ground, floaters and objects in a raw capture",
        description="Prepare a raw capture: mark floaters (faint, isolated Gaussians), find the up direction "
        "(floor/table plane, else the object's flat base or shape), the ground and the objects. Nothing is "
        "removed: every Gaussian gets `role` (0 object, 1 background, 2 ground, 3 floater) and `object_id` "
        "(-1 none). Decisions go to OUT.prepare.json (see docs/prepare.md).",
        epilog="example: pixie prepare capture.ply prepared.ply --up -y",
    )
    p.add_argument("input", metavar="IN", help="3D Gaussian splat")
    p.add_argument("output", metavar="OUT.ply", help="prepared splat to write (+ OUT.prepare.json)")
    add_prepare_options(p, skip=False)
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file")
    add_drop_invalid_option(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..atomic import check_distinct_output
    from ..prepare import parse_crop, parse_up
    from ..splat import read_splat_valid, write_splat

    check_distinct_output(args.input, args.output, args.force)
    parse_up(args.up)
    parse_crop(args.crop)
    cloud = read_splat_valid(args.input, args.drop_invalid)
    out, scene = prepare_from_args(cloud, args)
    write_splat(out, args.output)
    write_sidecar(scene, args.output)
    return 0
