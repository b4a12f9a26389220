"""Benchmark (issue 12): how a checkpoint's held-out accuracy and MSE depend on how much of the grid the object fills.

`annotate` and training map an object's centres' bounding box onto the 64³ grid with a margin
(FeatureSpec.margin, 0.05: the object spans 0.9 of the grid). A user's crop, a ground plane or leftover
background change that framing, and one real capture read differently with it: the redplant's foliage
is soft with the default grid and stiff when cropped to its object box (docs/model_card.md, "Candidates r51
and r52"). This script measures the same effect on generated held-out objects, where the answer is known:
each checkpoint is evaluated per Gaussian (`pixie evaluate`'s loop) with the margin set to each value of
`--margins`, the first row of every checkpoint (the margin it was trained with) being the baseline. Figures
go in docs/benchmarks.md; no speed target.

    python benchmarks/bench_framing.py DATA_DIR                          # the shipped checkpoint
    python benchmarks/bench_framing.py DATA_DIR --checkpoint cand.pt --margins 0.05,0.125,0.2,0.25

DATA_DIR holds a split made by `pixie generate` (e.g. `pixie generate ho --count 130 --split test --seed 1200
--gaussians 20000`); ~40 s per checkpoint and margin for 130 objects of 20k Gaussians on 2 CPU cores.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from pixie_gs.model.checkpoint import load_checkpoint
from pixie_gs.model.data import DeviceStore, load_split
from pixie_gs.model.evaluate import evaluate_store


def framing_rows(checkpoint: str | None, data_dir: str, split: str, margins: list[float]) -> list[dict]:
    """One row per margin: the checkpoint's per-Gaussian accuracy and average MSE with that margin."""
    loaded = load_checkpoint(checkpoint)
    records, _ = load_split(data_dir, split, list(loaded.features.extra_names))
    store = DeviceStore(records, "cpu")
    rows = []
    for margin in [loaded.features.margin] + [m for m in margins if m != loaded.features.margin]:
        t0 = time.perf_counter()
        probe = replace(loaded, features=replace(loaded.features, margin=margin))
        g = evaluate_store(probe, store, 4)["gaussian"]
        rows.append({"margin": margin, "object_span": round(1 - 2 * margin, 4), "accuracy": g["accuracy"],
                     "mse_avg": g["mse_avg"], "seconds": round(time.perf_counter() - t0, 1)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data_dir", help="dataset folder made by `pixie generate` (the split inside it)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--checkpoint", action="append", default=None, help="checkpoint (repeatable; default shipped)")
    ap.add_argument("--margins", default="0.05,0.125,0.2,0.25",
                    help="grid margins to try, comma-separated (each in 0–0.45; default 0.05,0.125,0.2,0.25)")
    ap.add_argument("--json", default=None, help="also write every figure as JSON")
    args = ap.parse_args()
    margins = [float(m) for m in args.margins.split(",")]
    if not all(0.0 <= m <= 0.45 for m in margins):
        raise SystemExit(f"--margins must lie in 0–0.45, got {args.margins}")
    results = []
    for ck in args.checkpoint or [None]:
        rows = framing_rows(ck, args.data_dir, args.split, margins)
        name = Path(ck).name if ck else "shipped"
        base = rows[0]
        for r in rows:
            print(f"{name:28s} margin {r['margin']:.3f} (object spans {r['object_span']:.2f} of the grid): "
                  f"accuracy {r['accuracy']:.4f} ({r['accuracy'] - base['accuracy']:+.4f})  "
                  f"avg MSE {r['mse_avg']:.4f} ({r['mse_avg'] - base['mse_avg']:+.4f})  ({r['seconds']:.0f} s)",
                  flush=True)
        results.append({"checkpoint": ck or "shipped", "rows": rows})
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
