"""Benchmark (issue 12): how one teacher pool's labels differ from another's on the same real splats.

Why: stop 57 relabelled the teacher pool with r59 (r58 had labelled stop 56's) and every candidate trained on it
read real wooden furniture softer. Relabelling with each new checkpoint can shrink the spread of E from one
generation to the next (docs/model_card.md, "Stop 57"). This script pairs the objects of two pools made from the
same sources (`python -m pixie_gs.dataset.teacher_pool … --checkpoint A` and `… --checkpoint B`) and prints, per
object, the median log10 E (Pa) of each, then the least-squares line B = slope · A + intercept over the objects,
the spread (standard deviation) of each, the mean shift of the objects A reads stiffer than 10^8.5 Pa and softer
than 10^7 Pa, and the fixed point intercept / (1 − slope) that repeated relabelling would pull towards. A slope
below 1 with a fixed point inside the spread is the compression. No speed target: a correctness benchmark.

    python benchmarks/bench_pool_drift.py /tmp/pool58 .pool/pool            # ~5 s for 44 objects of 12k
    python benchmarks/bench_pool_drift.py /tmp/pool58 .pool/pool --json drift.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pixie_gs.dataset.loader import list_objects, load_object
from pixie_gs.dataset.teacher_pool import POOL_SPLIT

STIFF_LOG10_E = 8.5  # objects read stiffer than this (wood, hard plastic, stone) …
SOFT_LOG10_E = 7.0   # … and softer than this (foam, fabric, leaves), in log10 Pa


def median_log10_e(pool: Path) -> dict[tuple[str, int], float]:
    """(source file name, object number) → median log10 E (Pa) of that pool object's labels."""
    out = {}
    for path in list_objects(pool, POOL_SPLIT):
        cloud, record = load_object(path)
        out[(Path(record["source"]).name, int(record["object"]))] = float(np.median(np.log10(cloud.get_materials()[1])))
    return out


def drift(a: dict[tuple[str, int], float], b: dict[tuple[str, int], float]) -> dict:
    """The line b = slope · a + intercept over the objects both pools hold, the spreads and the shifts."""
    keys = sorted(set(a) & set(b))
    if len(keys) < 2:
        raise SystemExit(f"the pools share {len(keys)} object(s): made from other sources?")
    x = np.array([a[k] for k in keys])
    y = np.array([b[k] for k in keys])
    slope, intercept = np.polyfit(x, y, 1)
    stiff, soft = x > STIFF_LOG10_E, x < SOFT_LOG10_E
    return {"objects": len(keys), "slope": float(slope), "intercept": float(intercept),
            "spread_a": float(x.std()), "spread_b": float(y.std()),
            "fixed_point_log10_e": float(intercept / (1 - slope)) if abs(1 - slope) > 1e-3 else None,
            "stiff_objects": int(stiff.sum()), "stiff_shift": float((y - x)[stiff].mean()) if stiff.any() else None,
            "soft_objects": int(soft.sum()), "soft_shift": float((y - x)[soft].mean()) if soft.any() else None,
            "per_object": {f"{s}#{o}": [a[(s, o)], b[(s, o)]] for s, o in keys}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pool_a", type=Path, help="the older pool (a folder `python -m pixie_gs.dataset.teacher_pool` wrote)")
    ap.add_argument("pool_b", type=Path, help="the newer pool, made from the same sources")
    ap.add_argument("--json", type=Path, default=None, help="also write every figure as JSON")
    args = ap.parse_args()
    r = drift(median_log10_e(args.pool_a), median_log10_e(args.pool_b))
    print(f"{'object':<36}{'A':>8}{'B':>8}{'B − A':>8}   (median log10 E, Pa)")
    for name, (ea, eb) in sorted(r["per_object"].items(), key=lambda kv: kv[1][1] - kv[1][0]):
        print(f"{name[:35]:<36}{ea:8.2f}{eb:8.2f}{eb - ea:+8.2f}")
    fixed = "none (slope 1)" if r["fixed_point_log10_e"] is None else f"10^{r['fixed_point_log10_e']:.1f} Pa"
    print(f"\n{r['objects']} objects: B = {r['slope']:.3f} · A {r['intercept']:+.3f}; spread {r['spread_a']:.2f} → "
          f"{r['spread_b']:.2f} decades; fixed point {fixed}")
    for kind, bound in (("stiff", f"> 10^{STIFF_LOG10_E}"), ("soft", f"< 10^{SOFT_LOG10_E}")):
        if r[f"{kind}_shift"] is not None:
            print(f"objects A reads {bound} Pa: {r[f'{kind}_objects']}, mean shift {r[f'{kind}_shift']:+.3f} decades")
    if args.json:
        args.json.write_text(json.dumps(r, indent=1) + "\n")


if __name__ == "__main__":
    main()
