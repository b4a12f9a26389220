"""`pixie annotate IN.ply OUT.ply`: predict per-Gaussian materials and write them into the splat."""
from __future__ import annotations

import argparse

from ..devices import DEVICE_CHOICES, DEVICE_HELP
from .cmd_prepare import add_prepare_options, prepare_from_args, write_sidecar
from .options import add_drop_invalid_option


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "annotate", parents=parents, help="predict materials (class, E, nu, density) for every Gaussian",
        description="Feature grid → 3D U-Net → nearest-voxel transfer. Writes material_id, E (Pa), nu and "
        "density (kg/m3) as extra vertex properties; every input property is kept.",
        epilog="example: pixie annotate scene.ply scene_materials.ply --rrd materials.rrd   "
        "(the capture is prepared first: up, ground, floaters, objects; see `pixie prepare --help`)",
    )
    p.add_argument("input", metavar="IN.ply", help="3D Gaussian splat")
    p.add_argument("output", metavar="OUT.ply", help="annotated splat to write")
    p.add_argument("--checkpoint", default=None, metavar="CKPT", help="model checkpoint (default: the shipped one)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help=DEVICE_HELP)
    add_prepare_options(p)
    p.add_argument("--rrd", default=None, metavar="FILE", help="rerun recording: splat by RGB, material, log E")
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file")
    add_drop_invalid_option(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..annotate import annotate_cloud
    from ..atomic import check_distinct_output
    from ..materials import MATERIAL_NAMES
    from ..progress import stage
    from ..splat import read_splat_valid, write_splat

    from ..prepare import parse_crop, parse_up

    check_distinct_output(args.input, args.output, args.force)
    given_up = parse_up(args.up)
    parse_crop(args.crop)
    cloud = read_splat_valid(args.input, args.drop_invalid)
    prepared_cloud, prepared = prepare_from_args(cloud, args)
    out = annotate_cloud(prepared_cloud, args.checkpoint, args.device, given_up if given_up is not None else "z",
                         prepared=prepared)
    if prepared is not None:  # the output keeps the input's properties + materials (roles: `pixie prepare`)
        out = _input_with_results(cloud, out, prepared.up_vector)
    if args.rrd:
        from ..viz import log_material_views, recording, send_layout

        with recording("pixie-annotate", args.rrd) as rec:
            log_material_views(rec, out)
            send_layout(rec)
    write_splat(out, args.output)
    write_sidecar(prepared, args.output)
    mid, E, nu, rho = out.get_materials()
    stage(f"wrote {args.output}")
    for m in np.unique(mid):
        sel = mid == m
        print(f"{MATERIAL_NAMES.get(int(m), str(m)):<13} {int(sel.sum()):>9} gaussians  E {np.median(E[sel]):.3g} Pa  "
              f"nu {np.median(nu[sel]):.3f}  density {np.median(rho[sel]):.4g} kg/m3")
    return 0


def _input_with_results(cloud, annotated, up_vector):
    """The input cloud plus the materials and confidence of `annotated`, and the up vector the
    preparation used as a `pixie up X Y Z` header comment, so `pixie simulate` on this file
    turns it the same way instead of estimating up again."""
    from ..prepare.updir import DECLARED_PREFIX, declared_up

    out = cloud.copy()
    out.set_materials(*annotated.get_materials())
    if annotated.has("confidence"):
        out.set("confidence", annotated.get("confidence"))
    if declared_up(out.comments) is None:
        x, y, z = (float(v) for v in up_vector)
        out.comments = list(out.comments) + [f"{DECLARED_PREFIX} {x:.6g} {y:.6g} {z:.6g}"]
    return out

