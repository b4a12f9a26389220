"""Benchmark (issue 12): how stiff a checkpoint reads the leaves of generated house plants, by leaf shape.

The second real set's potted plant (broad flat leaves) comes out with foliage at ~1e9 Pa, stiff as wood,
while its labels say leaves are soft. Repainting the capture's foliage did not move the reading much
(docs/model_card.md, "Broad-leaved house plants"), so the shape is the suspect. This script tests that on
generated objects, whose true labels are known: potted broadleaf trees from the test split, grouped as
  - broad-leaved house plants (`shape.broad_leaves`: flat leaf sheets, since stop 43),
  - clump house plants (foliage clumps down to the pot),
  - potted trees (clumps on a crown),
and for each checkpoint prints, per group, the median predicted E of the leaf Gaussians (Pa), the median
error of log10 E against each object's own leaf label (decades, signed: + reads too stiff), and the share
of leaf Gaussians read within one decade of their label. No speed target: a correctness benchmark.

    python benchmarks/bench_leafy_plants.py                                   # shipped checkpoint, ~10 s
    python benchmarks/bench_leafy_plants.py --checkpoint a.pt b.pt --per-group 8 --json leafy.json
    python benchmarks/bench_leafy_plants.py --per-group 24 --per-plant      # does it read stems and leaves apart?
    python benchmarks/bench_leafy_plants.py --split-dir bl/train --per-group 16 --per-plant --checkpoint a.pt
                                           # the plants a run trained on (a generated split, in index order)

With `--per-plant`, each broad-leaved plant's row: how far its stems' colour is from its leaves', its leaves'
median error, the share of its stems read softer than 1e7 Pa (stems are labelled 1e9–1e10 Pa) and the mean
squared log10 E error over its Gaussians, then the medians of the first two and the mean of the last over the
plants.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pixie_gs.annotate import annotate_cloud
from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.generate import object_seed
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.progress import set_quiet

GROUPS = ("broad-leaved house plant", "clump house plant", "potted tree")


def group_of(shape: dict) -> str | None:
    """The group a generated tree belongs to, or None for trees outside the comparison (unpotted, conifer)."""
    if shape.get("kind") != "broadleaf" or not shape.get("pot"):
        return None
    if "broad_leaves" in shape:
        return GROUPS[0]
    return GROUPS[1] if shape.get("houseplant") else GROUPS[2]


def first_per_group(candidates, per_group: int) -> list[tuple[str, object, dict]]:
    """(group, cloud, record) for the first `per_group` potted broadleaf trees of each group among `candidates`,
    an iterable of (record, load_cloud) pairs in order; a cloud is loaded only when its tree is kept, and the
    iteration stops once every group is full."""
    found: dict[str, list] = {g: [] for g in GROUPS}
    for record, load_cloud in candidates:
        group = group_of(record.get("shape", {}))
        if group is not None and len(found[group]) < per_group:
            found[group].append((group, load_cloud(), record))
        if all(len(v) >= per_group for v in found.values()):
            break
    return [item for g in GROUPS for item in found[g]]


def split_objects(folder: Path, per_group: int) -> list[tuple[str, object, dict]]:
    """(group, cloud, record) for up to `per_group` potted broadleaf trees of each group in a generated split
    folder (`pixie generate` output, e.g. one `scripts/filter_split.py` kept), in its index order: the objects
    an overfit check trained on, read back by the same figures."""
    from pixie_gs.splat import read_splat

    def candidates():
        for entry in json.loads((folder / "index.json").read_text())["objects"]:
            record = json.loads((folder / f"{Path(entry['file']).stem}.json").read_text())
            yield record, lambda path=folder / entry["file"]: read_splat(path)

    return first_per_group(candidates(), per_group)


def draw_objects(per_group: int, gaussians: int, seed: int, max_draws: int = 2000) -> list[tuple[str, object, dict]]:
    """(group, cloud, record) for `per_group` test-split potted broadleaf trees of each group."""
    spec = load_class_table()["tree"]

    def candidates():
        for i in range(max_draws):
            cloud, record = build_object(spec, object_seed(seed, "test", i), gaussians)
            yield record, lambda cloud=cloud: cloud

    return first_per_group(candidates(), per_group)


SOFT_STEM_PA = 1e7  # a stem (labelled 1e9–1e10 Pa) read below this is read as soft as foliage


def plant_row(rgb: np.ndarray, leaves: np.ndarray, stems: np.ndarray, error: np.ndarray,
              E_pred: np.ndarray) -> dict:
    """One plant (rgb (M,3), boolean part masks, every Gaussian's log10 E error in decades, predicted E in Pa):
    distance of its stems' mean RGB from its leaves', the leaves' median error, the share of stem Gaussians
    read below SOFT_STEM_PA, and the mean squared error over all its Gaussians (decades²): does it read stems
    and leaves apart?"""
    return {"stem_leaf_rgb_distance": float(np.linalg.norm(rgb[stems].mean(0) - rgb[leaves].mean(0))),
            "leaf_median_log10_error": float(np.median(error[leaves])),
            "stems_read_soft": float(np.mean(E_pred[stems] < SOFT_STEM_PA)),
            "log10_E_mse": float(np.mean(error ** 2))}


def leaf_errors(checkpoint: str | None, objects: list) -> dict[str, dict]:
    """Per group: the leaf Gaussians' predicted E (Pa) and their log10 error against the labels; per
    broad-leaved plant also `plant_row`'s figures."""
    rows: dict[str, dict[str, list]] = {g: {"E": [], "err": [], "plants": []} for g in GROUPS}
    for group, cloud, record in objects:
        names = [p["name"] for p in record["parts"]]
        leaves, stems = (cloud.extras["part_id"] == names.index(n) for n in ("leaves", "trunk"))
        _, E_true, _, _ = cloud.get_materials()
        _, E_pred, _, _ = annotate_cloud(cloud, checkpoint, device="cpu").get_materials()
        error = np.log10(E_pred) - np.log10(E_true)
        rows[group]["E"].append(E_pred[leaves])
        rows[group]["err"].append(error[leaves])
        if group == GROUPS[0]:
            rows[group]["plants"].append(plant_row(cloud.rgb(), leaves, stems, error, E_pred))
    out = {}
    for group, r in rows.items():
        if not r["E"]:
            continue
        E, err = np.concatenate(r["E"]), np.concatenate(r["err"])
        out[group] = {"objects": len(r["E"]), "median_E_Pa": float(np.median(E)),
                      "median_log10_error": float(np.median(err)),
                      "share_within_1_decade": float(np.mean(np.abs(err) <= 1.0)),
                      "per_object_median_E_Pa": [float(np.median(e)) for e in r["E"]]}
        if r["plants"]:
            out[group]["plants"] = r["plants"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", nargs="+", default=[None], help="checkpoints (default: the shipped one)")
    ap.add_argument("--per-group", type=int, default=6, help="objects per group")
    ap.add_argument("--gaussians", type=int, default=12000)
    ap.add_argument("--seed", type=int, default=11, help="dataset seed of the test-split objects")
    ap.add_argument("--split-dir", type=Path, default=None, metavar="DIR/SPLIT",
                    help="read the trees of this generated split folder instead of drawing test-split ones")
    ap.add_argument("--per-plant", action="store_true",
                    help="also print each broad-leaved plant (stem-leaf colour distance, leaf error, stems read soft, "
                         "log10 E MSE) and the figures over the plants")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    set_quiet(True)
    t0 = time.perf_counter()
    if args.split_dir is not None:
        objects = split_objects(args.split_dir, args.per_group)
        print(f"{len(objects)} potted broadleaf trees from {args.split_dir} in {time.perf_counter() - t0:.0f} s")
    else:
        objects = draw_objects(args.per_group, args.gaussians, args.seed)
        print(f"{len(objects)} potted broadleaf trees (seed {args.seed}, test split, {args.gaussians} Gaussians) "
              f"in {time.perf_counter() - t0:.0f} s")
    report = {}
    for ckpt in args.checkpoint:
        name = ckpt or "shipped"
        report[name] = leaf_errors(ckpt, objects)
        for group, r in report[name].items():
            print(f"{name:>24}  {group:<25} {r['objects']:>2} objects  leaves median E {r['median_E_Pa']:.2g} Pa  "
                  f"log10 error {r['median_log10_error']:+.2f}  within 1 decade {r['share_within_1_decade']:.2f}  "
                  f"[{time.perf_counter() - t0:.0f} s]")
            if args.per_plant and "plants" in r:
                for p in sorted(r["plants"], key=lambda p: p["stem_leaf_rgb_distance"]):
                    print(f"{'':>26}stem-leaf RGB distance {p['stem_leaf_rgb_distance']:.3f}  leaf error "
                          f"{p['leaf_median_log10_error']:+.2f}  stems read < {SOFT_STEM_PA:.0e} Pa "
                          f"{p['stems_read_soft']:.2f}  log10 E MSE {p['log10_E_mse']:.2f}")
                med = {k: float(np.median([p[k] for p in r["plants"]])) for k in ("stems_read_soft", "leaf_median_log10_error")}
                mse = float(np.mean([p["log10_E_mse"] for p in r["plants"]]))
                print(f"{'':>26}over the plants: median stems read soft {med['stems_read_soft']:.2f}, median leaf "
                      f"error {med['leaf_median_log10_error']:+.2f}, mean log10 E MSE {mse:.2f} decades²")
    if args.json:
        args.json.write_text(json.dumps({"per_group": args.per_group, "gaussians": args.gaussians,
                                         "seed": args.seed, "results": report}, indent=1))


if __name__ == "__main__":
    main()
