"""Benchmark (issue 12): two objects of different categories in one splat, standing side by side.

Most generated training objects are one category alone (plus floaters; `pixie generate --pairs` makes
the pairs measured here a share of the training data), while real captures
often hold two touching things (a plant in a wooden frame, a guitar on a stand). This measures what the
shipped checkpoint does with them: held-out generated objects (clean, test-split seeds) are annotated
alone, then in pairs of different categories on one ground, their footprints touching (a gap of −10 % to
+20 % of the smaller footprint, in a random horizontal direction). Per object it reports the share of its
Gaussians given their true material class alone and in the pair, through the plain path (`annotate_cloud`,
+z up) and the default `pixie annotate` path (`prepare`, which splits objects that do not touch); an object
is "taken over" when it is right alone (≥ 0.9) and mostly wrong in the pair (< 0.5): the neighbour's
material spread over it. No speed target: a correctness benchmark; the baseline is the objects alone.

    python benchmarks/bench_pairs.py                       # 26 categories × 2 objects → 26 pairs, ~2 min on 2 cores
    python benchmarks/bench_pairs.py --per-class 1 --json pairs.json
    python benchmarks/bench_pairs.py --picture docs/pairs_example.png   # up to 4 pairs with an object taken over
    python benchmarks/bench_pairs.py --floor    # each pair on a floor disc, as a capture on a table or ground
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from test_robustness import predict  # noqa: E402

TAKEN_OVER_ALONE, TAKEN_OVER_PAIR = 0.9, 0.5


def accuracy(predicted: np.ndarray, truth: np.ndarray) -> float:
    return float((np.asarray(predicted) == np.asarray(truth)).mean())


def taken_over(row: dict, key: str) -> bool:
    """Right alone and mostly wrong in the pair (`key`: pair_plain or pair_prepared)."""
    return row["alone"] >= TAKEN_OVER_ALONE and row[key] < TAKEN_OVER_PAIR


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-class", type=int, default=2, help="objects per category (pairs: half of all objects)")
    ap.add_argument("--gaussians", type=int, default=8000, help="Gaussians per object (±20 %%)")
    ap.add_argument("--seed", type=int, default=88, help="test-split dataset seed of the objects")
    ap.add_argument("--device", default="cpu", help="torch device for the model (cpu, cuda)")
    ap.add_argument("--floor", action="store_true",
                    help="stand each pair on a floor disc (stationary; dataset/floor.py, 0.3 of the pair's Gaussians), "
                         "as a capture on a table or ground has")
    ap.add_argument("--json", default=None, help="also write every figure as JSON")
    ap.add_argument("--picture", default=None, metavar="PNG",
                    help="also draw up to 4 pairs where an object was taken over: RGB, true and predicted class")
    args = ap.parse_args()

    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.dataset.floor import with_floor
    from pixie_gs.dataset.pairs import side_by_side
    from pixie_gs.progress import set_quiet

    set_quiet(True)
    table = load_class_table()
    names = list(table)
    rng = np.random.default_rng(args.seed)
    objects = []
    for k in range(args.per_class):
        for name in names:
            index = k * len(names) + names.index(name)
            cloud, _ = build_object(table[name], object_seed(args.seed, "test", index), args.gaussians)
            objects.append((name, cloud))
    order = list(rng.permutation(len(objects)))
    pairs = []
    while len(order) >= 2:  # each object in one pair, with a partner of another category
        i = order.pop(0)
        j = next((o for o in order if objects[o][0] != objects[i][0]), None)
        if j is None:
            break
        order.remove(j)
        pairs.append((i, j))

    t0 = time.perf_counter()
    rows, drawn = [], []
    for i, j in pairs:
        (name_a, a), (name_b, b) = objects[i], objects[j]
        joined, _ = side_by_side(a, b, rng)
        if args.floor:
            joined, _ = with_floor(joined, rng, share=0.3)
        truth = joined.get("material_id")
        n_a = len(a)
        plain, _ = predict(joined, False, args.device)
        prepared, _ = predict(joined, True, args.device)
        for name, partner, cloud, part in ((name_a, name_b, a, slice(0, n_a)), (name_b, name_a, b, slice(n_a, None))):
            alone, _ = predict(cloud, False, args.device)
            rows.append({"category": name, "partner": partner,
                         "alone": accuracy(alone, cloud.get("material_id")),
                         "pair_plain": accuracy(plain[part], truth[part]),
                         "pair_prepared": accuracy(prepared[part], truth[part])})
        if len(drawn) < 4 and any(taken_over(r, "pair_plain") for r in rows[-2:]):
            drawn.append((f"{name_a} + {name_b}", joined, truth, plain))
        print(f"[{time.perf_counter() - t0:5.0f} s] {name_a:<18} + {name_b:<18} "
              f"alone {rows[-2]['alone']:.2f}/{rows[-1]['alone']:.2f}  pair {rows[-2]['pair_plain']:.2f}/"
              f"{rows[-1]['pair_plain']:.2f}  prepared {rows[-2]['pair_prepared']:.2f}/{rows[-1]['pair_prepared']:.2f}",
              flush=True)

    summary = {"objects": len(rows), "pairs": len(pairs)}
    for key in ("alone", "pair_plain", "pair_prepared"):
        summary[f"mean_{key}"] = float(np.mean([r[key] for r in rows]))
    for key in ("pair_plain", "pair_prepared"):
        summary[f"taken_over_{key}"] = sum(taken_over(r, key) for r in rows)
    print(f"\n{len(rows)} objects in {len(pairs)} pairs{' on a floor' if args.floor else ''}, {args.gaussians} "
          f"Gaussians each; share of each object's Gaussians given their true material class (mean over objects)")
    print(f"  alone (baseline)     {summary['mean_alone']:.3f}")
    for key, label in (("pair_plain", "in a pair, plain"), ("pair_prepared", "in a pair, prepared")):
        print(f"  {label:<20} {summary[f'mean_{key}']:.3f}  ratio to alone "
              f"{summary[f'mean_{key}'] / max(summary['mean_alone'], 1e-9):.3f}  taken over by the partner: "
              f"{summary[f'taken_over_{key}']} of {len(rows)}")
    print(f"total {time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "objects": rows}, indent=1))
    if args.picture and drawn:
        draw(drawn, args.picture)


def draw(drawn: list, out: str) -> None:
    """One row per pair: base colour, true material class, class predicted on the pair (plain path)."""
    from pixie_gs.render import contact_sheet, material_panels, save_png

    images, labels = [], []
    for title, cloud, truth, predicted in drawn:
        agree = float(np.mean(predicted == truth))
        row_images, row_labels = material_panels(cloud, truth, predicted, title,
                                                 f"predicted in the pair ({agree:.0%} right)", size=(260, 200))
        images += row_images
        labels += row_labels
    save_png(contact_sheet(images, labels, columns=3), out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
