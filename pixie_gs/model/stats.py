"""Store training-distribution grid statistics in a checkpoint that lacks them (out-of-distribution score).

`pixie train` records them itself (meta["feature_stats"]) from its training objects; this module (re)computes
them for a checkpoint from generated objects of the classes it was trained on, without touching its weights —
for an older checkpoint that lacks them, or to describe every kind of input the model was measured to
handle (capture-like objects and clean converted meshes, `--realistic-share`):

    python -m pixie_gs.model.stats CKPT [--count 100] [--classes tree,flowers,…|all] [--gaussians 12000]
                                        [--realistic-share 0.0]
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


def add_stats(checkpoint: str | Path, classes: list[str], count: int, n_gaussians: int, seed: int = 31,
              realistic_share: float = 0.0) -> dict:
    """Compute the statistics from `count` generated objects (train-split seeds, round-robin over
    `classes`; object i is capture-like when its place in the sequence falls in the first
    `realistic_share` of every 20, else clean converter output) and write them into the checkpoint's
    meta (with how they were made); returns them."""
    import torch

    from ..dataset.assemble import build_object
    from ..dataset.generate import object_seed
    from ..dataset.labels import load_class_table
    from .checkpoint import load_checkpoint

    loaded = load_checkpoint(checkpoint, "cpu")
    table = load_class_table()
    realistic = [(i % 20) < round(20 * realistic_share) for i in range(count)]
    clouds = (build_object(table[classes[i % len(classes)]], object_seed(seed, "train", i), n_gaussians,
                           realistic=realistic[i])[0] for i in range(count))
    stats = feature_stats(loaded, progress(clouds, "grid statistics", total=count, unit="obj"))
    stats["source"] = {"objects": count, "classes": len(classes), "gaussians": n_gaussians, "seed": seed,
                       "capture_like": int(sum(realistic)), "clean": count - int(sum(realistic))}
    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    meta = {k: v for k, v in payload.get("meta", {}).items() if k != "feature_stats_from"}  # (a soup's, now stale)
    payload["meta"] = {**meta, "feature_stats": stats}
    with atomic_path(checkpoint, suffix=".pt.tmp") as tmp:
        torch.save(payload, tmp)
    return stats


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--classes", default=",".join(PAPER_CLASSES))
    ap.add_argument("--gaussians", type=int, default=12000)
    ap.add_argument("--realistic-share", type=float, default=0.0,
                    help="share of capture-like objects (the rest are clean converter output; default 0)")
    args = ap.parse_args(argv)
    if args.classes == "all":
        from ..dataset.labels import load_class_table

        classes = list(load_class_table())
    else:
        classes = args.classes.split(",")
    stats = add_stats(args.checkpoint, classes, args.count, args.gaussians, realistic_share=args.realistic_share)
    print(f"{args.checkpoint}: feature statistics of {stats['objects']} objects stored")


if __name__ == "__main__":
    main()
