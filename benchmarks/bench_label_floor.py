"""The label-noise floor of a generated split: the lowest normalised MSE any model can reach from appearance.

Every part's E, ν and ρ are drawn per object from the class table's ranges (log-uniform E and ρ, uniform
ν), independently of anything the splat shows. A model that knows each Gaussian's category and part
exactly can do no better than predict that part's mean label, so its MSE is the within-(category, part)
variance of the labels. This script measures that variance on a split's own labels (read from the files,
no model involved), weighted per Gaussian like `pixie evaluate`'s per-Gaussian columns, and prints it
next to an evaluation's figures when given one (`pixie evaluate … --json`).

usage: python benchmarks/bench_label_floor.py DATA_DIR [--split test] [--eval EVAL.json]
"""
from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from pixie_gs.dataset.loader import list_objects, load_object
from pixie_gs.materials import normalize_physical

NAMES = ("log_E", "nu", "log_rho")


def group_sums(data_dir: str, split: str) -> dict[tuple[str, int], np.ndarray]:
    """Per (category, part_id): [count, Σx (3), Σx² (3)] of the normalised labels of its Gaussians."""
    sums: dict[tuple[str, int], np.ndarray] = defaultdict(lambda: np.zeros(7))
    for path in list_objects(data_dir, split):
        cloud, meta = load_object(path)
        _, E, nu, rho = cloud.get_materials()
        phys = normalize_physical(E, nu, rho).astype(np.float64)
        part = cloud.get("part_id")
        for pid in np.unique(part):
            x = phys[part == pid]
            sums[(meta["class"], int(pid))] += np.concatenate([[len(x)], x.sum(0), (x ** 2).sum(0)])
    return dict(sums)


def floors(sums: dict[tuple[str, int], np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Per-Gaussian MSE of the per-(category, part) mean predictor: overall and per category."""
    total, by_cat = np.zeros(4), defaultdict(lambda: np.zeros(4))
    for (cat, _), s in sums.items():
        n = s[0]
        sq = s[4:] - s[1:4] ** 2 / n  # Σ (x − mean)²
        row = np.concatenate([[n], sq])
        total += row
        by_cat[cat] += row
    overall = total[1:] / total[0]
    return overall, {c: r[1:] / r[0] for c, r in sorted(by_cat.items())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data_dir")
    ap.add_argument("--split", default="test")
    ap.add_argument("--eval", default=None, metavar="EVAL.json", help="a `pixie evaluate --json` of the same split")
    args = ap.parse_args()
    overall, by_cat = floors(group_sums(args.data_dir, args.split))
    ev = json.loads(Path(args.eval).read_text()) if args.eval else None
    print(f"label-noise floor of {args.data_dir}/{args.split} (per Gaussian, normalised units):")
    print("  " + "  ".join(f"{n} {v:.4f}" for n, v in zip(NAMES, overall)) + f"  avg {overall.mean():.4f}")
    if ev:
        g = ev["gaussian"]
        print(f"  model ({ev.get('checkpoint', '?')}): " + "  ".join(f"{n} {g['mse_' + n]:.4f}" for n in NAMES)
              + f"  avg {g['mse_avg']:.4f}  (excess over the floor {g['mse_avg'] - overall.mean():+.4f})")
    print(f"{'category':18s} {'floor avg':>9s} {'floor nu':>9s}" + (f" {'model avg':>9s}" if ev else ""))
    for cat, f in by_cat.items():
        model = ev["by_object_class"].get(cat, {}).get("mse_avg") if ev else None
        print(f"{cat:18s} {f.mean():9.4f} {f[1]:9.4f}" + (f" {model:9.4f}" if model is not None else ""))


if __name__ == "__main__":
    main()
