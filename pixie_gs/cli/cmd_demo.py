"""`pixie demo`: annotate the shipped potted tree and simulate it swaying in wind (< 2 min on CPU)."""
from __future__ import annotations

import argparse

from ..devices import DEVICE_CHOICES, DEVICE_HELP
from ..errors import InputError


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "demo", parents=parents, help="annotate + simulate the shipped potted tree in wind (the quick start)",
        description="End-to-end demo: predicts materials for the shipped potted-tree splat with the shipped "
        "checkpoint, simulates it under gravity swaying in a gust of wind with its pot held in place, and writes "
        "DIR/tree_annotated.ply, DIR/frames/frame_*.ply + tracks.npz, DIR/demo.rrd (rerun: RGB | material | "
        "log E side by side with a time slider), DIR/demo.gif and DIR/demo_strip.png (open without rerun) "
        "and DIR/scene.json. Re-running replaces these files. Under a minute on a 2-core CPU.",
        epilog="example: pixie demo --out pixie_demo && rerun pixie_demo/demo.rrd",
    )
    p.add_argument("--out", default="pixie_demo", metavar="DIR", help="output directory (default ./pixie_demo)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help=DEVICE_HELP)
    p.add_argument("--frames", type=int, default=45, metavar="N",
                   help="frames incl. frame 0, at 15 frames/s (default 45 = 3 s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the per-cell particle choice (default 0)")
    p.add_argument("--checkpoint", metavar="CKPT", default=None,
                   help="material model checkpoint (default: the shipped one)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..demo import DemoSettings, run_demo
    from ..progress import stage

    if args.frames < 2:
        raise InputError(f"--frames must be ≥ 2, got {args.frames}")
    if args.checkpoint:  # a bad checkpoint is refused before DIR is created (the model is cached for the run)
        from ..annotate import get_model
        from ..devices import resolve_torch_device

        get_model(args.checkpoint, resolve_torch_device(args.device))
    result = run_demo(args.out, DemoSettings(frames=args.frames, seed=args.seed, device=args.device,
                                             checkpoint=args.checkpoint))
    top = result.top_displacement_m
    stage(f"top of the {result.height_m:.2f} m tree: up to {100 * top[:, 0].max():.1f} cm downwind in the gust, "
          f"{100 * -top[-1, 2]:.1f} cm lower at the end (its own weight)")
    total = sum(result.seconds.values())
    stage(f"done in {total:.0f} s (" + ", ".join(f"{k} {v:.0f} s" for k, v in result.seconds.items()) + ")")
    for key in ("annotated", "frames", "rrd", "gif", "strip", "scene"):
        print(result.files[key])
    print(f"open {result.files['gif']} in any image viewer, or run: rerun {result.files['rrd']}")
    return 0
