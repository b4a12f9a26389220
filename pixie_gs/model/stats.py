"""Store training-distribution grid statistics in a checkpoint that lacks them (out-of-distribution score).

`pixie train` records them itself (meta["feature_stats"]); this module adds them to an older checkpoint
from generated objects of the classes it was trained on, without touching its weights:

    python -m pixie_gs.model.stats CKPT [--count 100] [--classes tree,flowers,…] [--gaussians 12000]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..progress import progress

PAPER_CLASSES = ["tree", "flowers", "shrubs", "grass", "rubber_ducks_toys", "sport_balls", "soda_cans",
                 "metal_crates", "sand", "snow_mud"]


def feature_stats(loaded, clouds) -> dict:
    """Mean and std over `clouds` of `object_feature_summary` on the checkpoint's own feature grid."""
    import torch

    from ..field import feature_grid
    from .predict import grid_channel_names, object_feature_summary

    spec = loaded.features
    rows = []
    for cloud in clouds:
        g = feature_grid(cloud, spec.resolution, list(spec.extra_names), filter_voxels=spec.filter_voxels,
                         margin=spec.margin)
        rows.append(object_feature_summary(torch.as_tensor(g.values)[None], torch.as_tensor(g.occupancy)[None])[0])
    f = torch.stack(rows).double()
    return {"channels": grid_channel_names(spec.extra_names) + ["log10_occupied_share"], "objects": len(rows),
            "mean": [round(float(v), 6) for v in f.mean(0)], "std": [round(float(v), 6) for v in f.std(0)]}


def add_stats(checkpoint: str | Path, classes: list[str], count: int, n_gaussians: int, seed: int = 31) -> dict:
    """Compute the statistics from `count` clean generated objects (train-split seeds, round-robin over
    `classes`) and write them into the checkpoint's meta; returns them."""
    import torch

    from ..dataset.assemble import build_object
    from ..dataset.generate import object_seed
    from ..dataset.labels import load_class_table
    from .checkpoint import load_checkpoint

    loaded = load_checkpoint(checkpoint, "cpu")
    table = load_class_table()
    clouds = (build_object(table[classes[i % len(classes)]], object_seed(seed, "train", i), n_gaussians)[0]
              for i in range(count))
    stats = feature_stats(loaded, progress(clouds, "grid statistics", total=count, unit="obj"))
    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    payload["meta"] = {**payload.get("meta", {}), "feature_stats": stats}
    with atomic_path(checkpoint, suffix=".pt.tmp") as tmp:
        torch.save(payload, tmp)
    return stats


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--classes", default=",".join(PAPER_CLASSES))
    ap.add_argument("--gaussians", type=int, default=12000)
    args = ap.parse_args(argv)
    stats = add_stats(args.checkpoint, args.classes.split(","), args.count, args.gaussians)
    print(f"{args.checkpoint}: feature statistics of {stats['objects']} objects stored")


if __name__ == "__main__":
    main()
