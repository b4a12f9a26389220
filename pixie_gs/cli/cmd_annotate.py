"""`pixie annotate IN.ply OUT.ply`: predict per-Gaussian materials and write them into the splat.

With a folder, a glob or a manifest as IN and a folder as OUT it runs in batch mode (pixie_gs/batch)."""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ..devices import DEVICE_CHOICES, DEVICE_HELP
from ..batch.command import add_batch_options
from .cmd_prepare import add_prepare_options
from .options import add_drop_invalid_option

if TYPE_CHECKING:
    from ..batch.steps import AnnotateOptions


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "annotate", parents=parents, help="predict materials (class, E, nu, density) for every Gaussian",
        description="Feature grid → 3D U-Net → nearest-voxel transfer. Writes material_id, E (Pa), nu and "
        "density (kg/m3) as extra vertex properties; every input property is kept.",
        epilog="example: pixie annotate scene.ply scene_materials.ply --rrd materials.rrd   "
        "(the capture is prepared first: up, ground, floaters, objects; see `pixie prepare --help`)   "
        "batch: pixie annotate 'library/*.ply' annotated/ --shard 0/4   (docs/batch.md)",
    )
    p.add_argument("input", metavar="IN", help="3D Gaussian splat; or, for batch mode, a folder, a quoted glob "
                   "('lib/**/*.ply') or a manifest (.txt: one path per line)")
    p.add_argument("output", metavar="OUT", help="annotated splat to write (batch mode: the output folder)")
    p.add_argument("--checkpoint", default=None, metavar="CKPT", help="model checkpoint (default: the shipped one)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help=DEVICE_HELP)
    add_prepare_options(p)
    p.add_argument("--rrd", default=None, metavar="FILE", help="rerun recording: splat by RGB, material, log E")
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file (batch mode: annotate "
                   "again the assets whose outputs are already finished)")
    add_drop_invalid_option(p)
    add_batch_options(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..atomic import check_distinct_output
    from ..batch.jobs import is_batch_input
    from ..batch.steps import AnnotateOptions, PreparingAhead, predict, read_prepared, write_result
    from ..errors import InputError
    from ..materials import MATERIAL_NAMES
    from ..progress import stage

    if is_batch_input(args.input):
        from ..batch.command import run_batch

        return run_batch(args)
    for flag in ("shard", "ray", "summary"):
        if getattr(args, flag) is not None:
            raise InputError(f"--{flag} is for batch mode (IN a folder, a glob or a manifest); "
                             "this input is one file", args.input)
    check_distinct_output(args.input, args.output, args.force)
    opts = AnnotateOptions.from_args(args)
    opts.validate()
    ahead = PreparingAhead.start(args.input, opts)  # reads + prepares in a worker while torch loads here
    if ahead is None:
        asset = read_prepared(args.input, opts, announce=True)
    else:
        with ahead:
            model_error = _load_model(opts)
            asset = ahead.result()  # the input's own error first, as when read in-process
        if model_error is not None:
            raise model_error
    out = predict(asset, opts)
    if args.rrd:
        from ..viz import log_material_views, recording, send_layout

        with recording("pixie-annotate", args.rrd) as rec:
            log_material_views(rec, out)
            send_layout(rec)
    write_result(out, asset.prepared, args.output)
    mid, E, nu, rho = out.get_materials()
    stage(f"wrote {args.output}")
    for m in np.unique(mid):
        sel = mid == m
        print(f"{MATERIAL_NAMES.get(int(m), str(m)):<13} {int(sel.sum()):>9} gaussians  E {np.median(E[sel]):.3g} Pa  "
              f"nu {np.median(nu[sel]):.3f}  density {np.median(rho[sel]):.4g} kg/m3")
    args.exit_at_once = True  # all written and closed: the process may skip the interpreter's teardown (cli/main.py)
    return 0


def _load_model(opts: "AnnotateOptions") -> Exception | None:
    """Import torch and load the checkpoint on the device (`get_model` keeps it for `predict`); the
    error (a bad checkpoint or device) is returned, to be raised after the input's own errors."""
    from ..annotate import get_model
    from ..devices import resolve_torch_device

    try:
        get_model(opts.checkpoint, resolve_torch_device(opts.device))
    except Exception as exc:  # noqa: BLE001 - re-raised by the caller
        return exc
    return None
