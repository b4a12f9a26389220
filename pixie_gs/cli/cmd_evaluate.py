"""`pixie evaluate CKPT DATA_DIR`: the paper's accuracy/MSE table on a held-out split."""
from __future__ import annotations

import argparse

from ..devices import DEVICE_CHOICES, DEVICE_HELP


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "evaluate", parents=parents, help="material accuracy and normalised MSE on a held-out split",
        description="Material accuracy and MSE of normalised log10 E, nu, log10 density (and their average), "
        "per occupied voxel and per Gaussian, plus per-class accuracy tables.",
        epilog="example: pixie evaluate model.pt data/ --split test --json metrics.json",
    )
    p.add_argument("checkpoint", metavar="CKPT", help="checkpoint from `pixie train` ('default' = the shipped one)")
    p.add_argument("data_dir", metavar="DATA_DIR", help="dataset made by `pixie generate`")
    p.add_argument("--split", choices=["train", "val", "test"], default="test", help="split to score (default: the held-out test split)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help=DEVICE_HELP)
    p.add_argument("--limit", type=int, default=None, help="only the first K objects")
    p.add_argument("--workers", type=int, default=1, help="processes reading the dataset")
    p.add_argument("--json", default=None, metavar="FILE", help="also write the metrics as JSON")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    import json

    from ..atomic import atomic_path
    from ..devices import resolve_torch_device
    from ..errors import require_finite_result
    from ..model.checkpoint import load_checkpoint
    from ..model.evaluate import evaluate_split
    from ..model.metrics import format_table

    device = resolve_torch_device(args.device)
    loaded = load_checkpoint(None if args.checkpoint == "default" else args.checkpoint, device)
    summary = evaluate_split(loaded, args.data_dir, args.split, device, args.limit, args.workers)
    require_finite_result(_numbers(summary), "evaluation metrics", args.checkpoint)
    print(format_table(summary))
    if args.json:
        with atomic_path(args.json, suffix=".tmp") as tmp:
            tmp.write_text(json.dumps(summary, indent=1))
    return 0


def _numbers(tree, prefix: str = "") -> dict[str, float]:
    """Every float in a nested dict/list of metrics, keyed by its dotted path."""
    if isinstance(tree, dict):
        return {k: v for key, sub in tree.items() for k, v in _numbers(sub, f"{prefix}{key}.").items()}
    if isinstance(tree, (list, tuple)):
        return {k: v for i, sub in enumerate(tree) for k, v in _numbers(sub, f"{prefix}{i}.").items()}
    return {prefix.rstrip("."): float(tree)} if isinstance(tree, float) else {}
