"""`pixie train DATA_DIR --out CKPT`: train the material U-Net on a generated dataset."""
from __future__ import annotations

import argparse
import math

from ..devices import DEVICE_CHOICES, DEVICE_HELP


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "train", parents=parents, help="train the material network on a generated dataset",
        description="Train the feature-grid 3D U-Net on DATA_DIR/train (validated on DATA_DIR/val each epoch). "
        "The best weights by validation score go to CKPT; CKPT.state.pt holds what --resume needs. "
        "Started by torchrun, it trains data-parallel: each batch is split over the processes (one GPU each, "
        "or gloo on the CPU) and rank 0 writes the checkpoint and the log.",
        epilog="example: pixie train data/ --out model.pt --epochs 40 --device cuda --time-budget-s 300;  "
        "on 2 GPUs: torchrun --standalone --nproc_per_node 2 -m pixie_gs.cli.main train data/ --out model.pt "
        "--device cuda",
    )
    p.add_argument("data_dir", metavar="DATA_DIR", help="dataset made by `pixie generate` (train/ and val/ splits)")
    p.add_argument("--out", required=True, metavar="CKPT", help="checkpoint file to write (.pt)")
    p.add_argument("--epochs", type=int, default=30, help="passes over the train split (default 30)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help=DEVICE_HELP)
    p.add_argument("--time-budget-s", type=float, default=None, help="stop (and anneal the LR) within this wall time, s; with --resume it counts the time trained before")
    p.add_argument("--resume", action="store_true", help="continue from CKPT.state.pt")
    p.add_argument("--init", default=None, metavar="CKPT0", help="start from this checkpoint's weights (fine-tuning)")
    p.add_argument("--batch-size", type=int, default=8,
                   help="objects per optimiser step, over all processes (default 8)")
    p.add_argument("--lr", type=float, default=2e-3, help="Adam learning rate (default 2e-3)")
    p.add_argument("--warmup-steps", type=int, default=100, metavar="S",
                   help="optimiser steps over which the learning rate rises linearly to --lr (default 100); a short "
                        "fine-tune on few objects needs fewer, or it ends before the rate is reached")
    p.add_argument("--seed", type=int, default=0, help="seed for initialisation, shuffling and augmentation")
    p.add_argument("--inputs", choices=["full", "rgb", "occupancy"], default="full",
                   help="input channels: every feature (default), occupancy+RGB, or occupancy only (ablation)")
    p.add_argument("--base-channels", type=int, default=16, help="U-Net width at full resolution (default 16)")
    p.add_argument("--multipliers", default="1,2,4", help="U-Net width multipliers per level, e.g. 1,2,4")
    p.add_argument("--res-blocks", type=int, default=1, help="residual blocks per U-Net level (default 1)")
    p.add_argument("--context-width", type=int, default=0, metavar="W",
                   help="hidden width of an object-context branch: every voxel also sees a summary of the whole "
                   "grid (default 0: none). With --init from a checkpoint without one, it starts at zero")
    p.add_argument("--resolution", type=int, default=64, help="grid cells per side (divisible by 2^(levels-1))")
    p.add_argument("--no-augment", action="store_true", help="no yaw/flip/scale/colour augmentation")
    p.add_argument("--tilt-deg", type=float, default=0.0, metavar="DEG",
                   help="augmentation: tilt a share of the objects (--tilt-share, default 0.5) about a random "
                   "horizontal axis by up to DEG degrees (default 0: none)")
    p.add_argument("--tilt-share", type=float, default=0.5, help="share of objects tilted (with --tilt-deg)")
    p.add_argument("--frame-margin-max", type=float, default=0.0, metavar="M",
                   help="augmentation: draw each object's grid margin between the checkpoint's (0.05: the object "
                   "spans 0.9 of the grid) and M, so it learns objects that fill less of their grid, as a crop or "
                   "leftover capture makes them (benchmarks/bench_framing.py; default 0: off)")
    p.add_argument("--decal-share", type=float, default=0.0, metavar="S",
                   help="augmentation: paint 2–8 balls of random colour over a share S of the training objects, as "
                   "labels, prints and paint do on real ones, so colour contrast alone does not say soft "
                   "(benchmarks/real_holdout: a printed metal helmet; default 0: off)")
    p.add_argument("--hue-share", type=float, default=0.0, metavar="S",
                   help="augmentation: turn the hue of a share S of the training objects by up to ±180° and scale "
                   "their saturation by 0.3–1.5, so a material is not read from a palette alone "
                   "(benchmarks/real_holdout: a photographed plant; default 0: off)")
    p.add_argument("--workers", type=int, default=1, help="processes reading the dataset")
    p.add_argument("--limit-train", type=int, default=None, help="use only the first K train objects")
    p.add_argument("--limit-val", type=int, default=None, help="use only the first K val objects")
    p.add_argument("--build-objects", type=int, default=None, metavar="N",
                   help="objects whose input grids are built in one pass, several steps' worth (default: up to "
                   "128 on CUDA as memory allows, one step on the CPU)")
    p.add_argument("--part-balance", type=float, default=0.0, metavar="ALPHA",
                   help="weigh each voxel of the loss by (object voxels / (parts · part voxels))^ALPHA, a part being "
                   "the voxels of one object with one material class and one decade of E, so an object's small "
                   "parts (a plant's stems, a mug's handle) count as much as its large ones at ALPHA 1; each "
                   "object keeps its share of the loss; validation stays unweighted (default 0: off)")
    p.add_argument("--anchor-weight", type=float, default=0.0, metavar="W",
                   help="with --init: add W · Σ (θ − θ_init)² to the loss (L2-SP), keeping a fine-tune near its start "
                   "weights; every epoch logs that sum as drift_sq (default 0: no penalty)")
    p.add_argument("--freeze", default="", metavar="PARTS",
                   help="comma-separated network parts kept at --init's weights: 'encoder' (everything up to the "
                        "bottleneck) or part names (projector, stem, down_blocks, …); default: none")
    p.add_argument("--distill", default=None, metavar="CKPT",
                   help="hold the outputs near this checkpoint's: add W · (KL of the class distributions + squared "
                   "difference of E, ν, ρ, normalised) on the occupied voxels of every training object whose kind "
                   "is not in --distill-skip; keeps a fine-tune's old kinds (docs/training.md)")
    p.add_argument("--distill-weight", type=float, default=None, metavar="W",
                   help="with --distill: the weight W of that term (default 1)")
    p.add_argument("--distill-skip", default="", metavar="KINDS",
                   help="with --distill: object kinds (classes.json names, comma-separated) left to the labels "
                   "alone, e.g. the kinds the teacher never saw")
    p.add_argument("--teacher-pool", default=None, metavar="DIR",
                   help="add the train split of DIR (real splats labelled by a teacher: python -m "
                   "pixie_gs.dataset.teacher_pool) to the training objects; with --distill the student is also held "
                   "to the teacher's outputs on them (kind real_pool)")
    p.add_argument("--teacher-pool-repeat", type=int, default=1, metavar="K",
                   help="with --teacher-pool: list each of its objects K times per epoch (each augmented on its own)")
    p.add_argument("--keep-epochs", action="store_true",
                   help="also write every epoch's weights as CKPT_STEM.epochNN.pt (to score each on real captures, "
                   "e.g. benchmarks/bench_real_set.py, before picking one)")
    p.add_argument("--log", "--log-json", dest="log", default=None, metavar="JSON",
                   help="write the per-epoch history here (under torchrun write --log-json: torchrun's own "
                   "parser takes --log for an abbreviation of its options)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..devices import resolve_torch_device
    from ..errors import InputError
    from ..model import distributed
    from ..model.train import TrainConfig, frozen_part_names, train
    from ..progress import set_quiet

    try:
        mults = [int(v) for v in args.multipliers.split(",")]
    except ValueError:
        raise InputError(f"--multipliers must be integers separated by commas (got '{args.multipliers}')") from None
    if args.resolution % (2 ** (len(mults) - 1)):
        raise InputError(f"--resolution {args.resolution} is not divisible by 2^{len(mults) - 1}")
    for name in ("epochs", "batch_size", "base_channels", "res_blocks", "workers", "build_objects"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise InputError(f"--{name.replace('_', '-')} must be ≥ 1")
    if args.context_width < 0:
        raise InputError("--context-width must be ≥ 0")
    if args.warmup_steps < 0:
        raise InputError(f"--warmup-steps must be ≥ 0 (got {args.warmup_steps})")
    # a network that `annotate` would refuse to load (model/checkpoint.py's ranges) is refused before training
    from ..model.checkpoint import CHANNELS_RANGE, MAX_LEVELS, MAX_RES_BLOCKS, MULTIPLIER_RANGE, RESOLUTION_RANGE

    for flag, value, high in (("--base-channels", args.base_channels, CHANNELS_RANGE[1]),
                              ("--context-width", args.context_width, CHANNELS_RANGE[1]),
                              ("--res-blocks", args.res_blocks, MAX_RES_BLOCKS),
                              ("--resolution", args.resolution, RESOLUTION_RANGE[1])):
        if value > high:
            raise InputError(f"{flag} must be ≤ {high} (a larger network is refused when loaded; got {value})")
    if args.resolution < RESOLUTION_RANGE[0]:
        raise InputError(f"--resolution must be ≥ {RESOLUTION_RANGE[0]} (got {args.resolution})")
    if len(mults) > MAX_LEVELS or not all(MULTIPLIER_RANGE[0] <= m <= MULTIPLIER_RANGE[1] for m in mults):
        raise InputError(f"--multipliers must be 1 to {MAX_LEVELS} integers within {MULTIPLIER_RANGE[0]}–"
                         f"{MULTIPLIER_RANGE[1]} (got '{args.multipliers}')")
    if not (0.0 <= args.tilt_deg <= 90.0 and 0.0 <= args.tilt_share <= 1.0):
        raise InputError("--tilt-deg must be within 0–90 and --tilt-share within 0–1")
    if not 0.0 <= args.frame_margin_max <= 0.45:
        raise InputError(f"--frame-margin-max must be within 0–0.45 (got {args.frame_margin_max})")
    for flag, value in (("--decal-share", args.decal_share), ("--hue-share", args.hue_share)):
        if not 0.0 <= value <= 1.0:
            raise InputError(f"{flag} must be within 0–1 (got {value})")
    if not 0.0 <= args.part_balance <= 1.0:
        raise InputError(f"--part-balance must be within 0–1 (got {args.part_balance})")
    if not (math.isfinite(args.anchor_weight) and args.anchor_weight >= 0.0):
        raise InputError(f"--anchor-weight must be a finite number ≥ 0 (got {args.anchor_weight})")
    if args.anchor_weight > 0 and not args.init:
        raise InputError("--anchor-weight needs --init (the weights to stay near)")
    distill_weight = 1.0 if args.distill_weight is None else args.distill_weight
    if not (math.isfinite(distill_weight) and distill_weight >= 0.0):
        raise InputError(f"--distill-weight must be a finite number ≥ 0 (got {distill_weight})")
    distill_skip = [k for k in (v.strip() for v in args.distill_skip.split(",")) if k]
    if (distill_skip or args.distill_weight is not None) and not args.distill:
        raise InputError(f"{'--distill-skip' if distill_skip else '--distill-weight'} needs --distill (the teacher "
                         "checkpoint)")
    freeze = [k for k in (v.strip() for v in args.freeze.split(",")) if k]
    frozen_part_names(freeze)
    if freeze and not args.init:
        raise InputError("--freeze needs --init (the weights to keep)")
    if args.teacher_pool_repeat < 1:
        raise InputError(f"--teacher-pool-repeat must be ≥ 1 (got {args.teacher_pool_repeat})")
    if args.teacher_pool_repeat != 1 and not args.teacher_pool:
        raise InputError("--teacher-pool-repeat needs --teacher-pool (the pool to repeat)")
    cfg = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, warmup_steps=args.warmup_steps,
                      time_budget_s=args.time_budget_s,
                      seed=args.seed, augment=not args.no_augment, workers=args.workers,
                      tilt_max_deg=args.tilt_deg, tilt_share=args.tilt_share, margin_max=args.frame_margin_max,
                      decal_share=args.decal_share, hue_share=args.hue_share,
                      limit_train=args.limit_train, limit_val=args.limit_val, input_mode=args.inputs,
                      init_from=args.init, objects_per_build=args.build_objects, keep_epochs=args.keep_epochs,
                      part_balance=args.part_balance, anchor_weight=args.anchor_weight, freeze=freeze,
                      distill_from=args.distill,
                      distill_weight=distill_weight, distill_skip=distill_skip,
                      teacher_pool=args.teacher_pool, teacher_pool_repeat=args.teacher_pool_repeat,
                      model={"base_channels": args.base_channels, "multipliers": mults, "res_blocks": args.res_blocks,
                             "context_width": args.context_width},
                      features={"resolution": args.resolution})
    ctx = distributed.context_from_env()  # several processes when started by torchrun
    device = distributed.join(ctx, resolve_torch_device(args.device))
    if not ctx.is_main:
        set_quiet(True)  # rank 0 alone reports
    try:
        meta = train(args.data_dir, args.out, cfg, device, args.resume, args.log, ctx)
    finally:
        distributed.leave(ctx)
    if ctx.is_main:
        best = meta.get("val", {}).get("voxel", {})
        print(f"checkpoint {args.out}: best epoch {meta.get('best_epoch')}  "
              f"val accuracy {best.get('accuracy', 0):.4f}  val avg mse {best.get('mse_avg', 0):.4f}")
    return 0
