"""Store training-distribution grid statistics in a checkpoint that lacks them (out-of-distribution score).

`pixie train` records them itself (meta["feature_stats"]) from its training objects; this module (re)computes
them for a checkpoint from generated objects of the classes it was trained on, without touching its weights —
for an older checkpoint that lacks them, or to describe every kind of input the model was measured to
handle (capture-like objects and clean converted meshes, `--realistic-share`):

    python -m pixie_gs.model.stats CKPT [--count 100] [--classes tree,flowers,…|all] [--gaussians 12000]
                                        [--realistic-share 0.0] [--by-look]
    python -m pixie_gs.model.stats CKPT --copy-from OTHER.pt

`--copy-from OTHER.pt` stores OTHER's statistics instead of computing any (they describe the inputs, not the
weights, so a checkpoint trained further on the same feature grid can carry the shipped one's unchanged).
`--by-look` keeps the checkpoint's own statistics and adds those of the capture-like and the clean objects
apart (meta["feature_stats"]["groups"]): one mean and spread over a mix of two looks puts a clean converted
mesh (constant opacity, dense surface) far from the middle of both, and the out-of-distribution score then
called correct answers on converted meshes a guess; with groups an object is in distribution when it is
close to the pooled statistics or to either look (model/predict.py `in_distribution_score`).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import InputError
from ..progress import progress

PAPER_CLASSES = ["tree", "flowers", "shrubs", "grass", "rubber_ducks_toys", "sport_balls", "soda_cans",
                 "metal_crates", "sand", "snow_mud"]


def object_summaries(loaded, clouds):
    """(K, C+1) float64 tensor: `object_feature_summary` of each cloud on the checkpoint's own feature grid."""
    import torch

    from ..field import feature_grid
    from .predict import object_feature_summary

    spec = loaded.features
    rows = []
    for cloud in clouds:
        g = feature_grid(cloud, spec.resolution, list(spec.extra_names), filter_voxels=spec.filter_voxels,
                         margin=spec.margin)
        rows.append(object_feature_summary(torch.as_tensor(g.values)[None], torch.as_tensor(g.occupancy)[None])[0])
    return torch.stack(rows).double()


def summary_stats(loaded, f) -> dict:
    """Mean and std over the rows of `f` (object summaries), with the channel names."""
    from .predict import grid_channel_names

    return {"channels": grid_channel_names(loaded.features.extra_names) + ["log10_occupied_share"],
            "objects": int(len(f)), "mean": [round(float(v), 6) for v in f.mean(0)],
            "std": [round(float(v), 6) for v in f.std(0)]}


def add_stats(checkpoint: str | Path, classes: list[str], count: int, n_gaussians: int | list[int], seed: int = 31,
              realistic_share: float = 0.0, by_look: bool = False) -> dict:
    """Compute the statistics from `count` generated objects (train-split seeds, round-robin over
    `classes`; object i is capture-like when its place in the sequence falls in the first
    `realistic_share` of every 20, else clean converter output) and write them into the checkpoint's
    meta (with how they were made); returns them. `n_gaussians`: one count, or several that the objects
    take in turn (training mixes sparse and dense splats, and the grid's density follows the count).
    `by_look`: keep the checkpoint's statistics (when it has them) and add the capture-like and the clean
    objects' apart, as `groups` (ValueError when the share and count do not give both looks)."""
    import torch

    from ..dataset.assemble import build_object
    from ..dataset.generate import object_seed
    from ..dataset.labels import load_class_table
    from .checkpoint import load_checkpoint

    loaded = load_checkpoint(checkpoint, "cpu")
    table = load_class_table()
    realistic = [(i % 20) < round(20 * realistic_share) for i in range(count)]
    if by_look and len(set(realistic)) < 2:
        raise ValueError("--by-look needs both looks: a --realistic-share and --count that give capture-like "
                         "and clean objects")
    counts = [n_gaussians] if isinstance(n_gaussians, int) else list(n_gaussians)
    clouds = (build_object(table[classes[i % len(classes)]], object_seed(seed, "train", i), counts[i % len(counts)],
                           realistic=realistic[i])[0] for i in range(count))
    f = object_summaries(loaded, progress(clouds, "grid statistics", total=count, unit="obj"))
    source = {"objects": count, "classes": len(classes), "gaussians": counts, "seed": seed,
              "capture_like": int(sum(realistic)), "clean": count - int(sum(realistic))}
    if by_look:
        looks = torch.as_tensor(realistic)
        stats = dict(loaded.meta.get("feature_stats") or summary_stats(loaded, f))
        stats["groups"] = [{"name": name, **summary_stats(loaded, f[mask])}
                           for name, mask in (("capture-like", looks), ("clean", ~looks))]
        stats["groups_source"] = source
    else:
        stats = {**summary_stats(loaded, f), "source": source}
    store_stats(checkpoint, torch.load(checkpoint, map_location="cpu", weights_only=True), stats)
    return stats


def store_stats(checkpoint: str | Path, payload: dict, stats: dict, copied_from: str | None = None) -> None:
    """Write `payload` (the checkpoint's own) back to `checkpoint` atomically with `stats` as its grid statistics,
    weights untouched; `feature_stats_from` names the checkpoint they were copied from, or goes (a soup's record
    of where its statistics came from is stale once they are recomputed)."""
    import torch

    meta = {k: v for k, v in payload.get("meta", {}).items() if k != "feature_stats_from"}
    payload["meta"] = {**meta, "feature_stats": stats, **({"feature_stats_from": copied_from} if copied_from else {})}
    with atomic_path(checkpoint, suffix=".pt.tmp") as tmp:
        torch.save(payload, tmp)


def copy_stats(checkpoint: str | Path, source: str | Path) -> dict:
    """Store `source`'s grid statistics (groups included) in `checkpoint`, weights untouched; returns them.
    InputError when `source` has none or its feature grid differs (the statistics would describe other inputs)."""
    from .checkpoint import read_payload

    target, donor = read_payload(Path(checkpoint)), read_payload(Path(source))
    stats = donor.get("meta", {}).get("feature_stats")
    if stats is None:
        raise InputError("it has no grid statistics to copy", source)
    if donor.get("features") != target.get("features"):
        raise InputError(f"its feature grid differs from {Path(checkpoint).name}'s: its statistics describe other inputs",
                         source)
    store_stats(checkpoint, target, stats, copied_from=Path(source).name)
    return stats


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--classes", default=",".join(PAPER_CLASSES))
    ap.add_argument("--gaussians", default="12000",
                    help="Gaussians per object, or several comma-separated that the objects take in turn")
    ap.add_argument("--realistic-share", type=float, default=0.0,
                    help="share of capture-like objects (the rest are clean converter output; default 0)")
    source = ap.add_mutually_exclusive_group()  # computed here (and perhaps grouped by look), or copied
    source.add_argument("--by-look", action="store_true",
                        help="keep the checkpoint's statistics and add the capture-like and clean objects' apart")
    source.add_argument("--copy-from", metavar="OTHER", default=None,
                        help="store OTHER checkpoint's statistics (same feature grid) instead of computing them")
    args = ap.parse_args(argv)
    if args.copy_from is not None:
        try:
            stats = copy_stats(args.checkpoint, args.copy_from)
        except InputError as exc:
            ap.error(str(exc))
        print(f"{args.checkpoint}: feature statistics of {stats['objects']} objects copied from {args.copy_from}")
        return
    if args.classes == "all":
        from ..dataset.labels import load_class_table

        classes = list(load_class_table())
    else:
        classes = args.classes.split(",")
    try:
        counts = [int(c) for c in args.gaussians.split(",")]
    except ValueError:
        ap.error(f"--gaussians takes whole numbers separated by commas (got {args.gaussians!r})")
    try:
        stats = add_stats(args.checkpoint, classes, args.count, counts, realistic_share=args.realistic_share,
                          by_look=args.by_look)
    except ValueError as exc:
        ap.error(str(exc))
    groups = ", ".join(f"{g['name']} {g['objects']}" for g in stats.get("groups", []))
    print(f"{args.checkpoint}: feature statistics of {stats['objects']} objects stored" + (f"; by look: {groups}" if groups else ""))


if __name__ == "__main__":
    main()
