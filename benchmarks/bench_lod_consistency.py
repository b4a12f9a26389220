"""Benchmark (issue 12): does a checkpoint read one object alike at two levels of detail?

A splat of one object can come with few large Gaussians or many small ones (a capture's training budget, a
viewer's level of detail, a converter's count). Its materials should not depend on that. Two sets of pairs:

- **another tool's** (the answer not known, only that the two should agree): 20 objects published by
  marcelpadilla/splats' mesh2splat at 10k and at 100k Gaussians (`bash benchmarks/lod_pairs_fetch.sh DIR`);
- **generated** (the control, the answer known): `--generated N` objects of every kind made by `pixie generate
  --clean` with one seed at 8,000 and at 60,000 Gaussians (the same shapes and labels).

Each splat goes through the default `pixie annotate` path (prepare, then the network); per pair the median
log10 E (Pa) and ρ (kg/m³) over the object's Gaussians and the majority class are compared. Printed per
checkpoint (the shipped one first, the baseline): mean, median and largest |Δ log10 E|, the class flips, and
for the generated pairs the mean |error| of the median log10 E against the true one. No speed target.

    bash benchmarks/lod_pairs_fetch.sh /tmp/lod
    python benchmarks/bench_lod_consistency.py /tmp/lod --checkpoint cand.pt --json lod.json
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

LOW, HIGH = "10k", "100k"  # the published levels of the tool's pairs
GENERATED_COUNTS = (8000, 60000)


def reading(cloud, checkpoint: str | None) -> dict:
    """The default annotate path's majority class and median log10 E, median ρ over the object's Gaussians."""
    from pixie_gs.annotate import annotate_cloud
    from pixie_gs.prepare import prepare_cloud
    from pixie_gs.prepare.scene import ROLE_OBJECT

    prepared, scene = prepare_cloud(cloud)
    mid, e_pa, _, rho = annotate_cloud(prepared, checkpoint, "cpu", prepared=scene).get_materials()
    mine = prepared.get("role") == ROLE_OBJECT
    ids, counts = np.unique(mid[mine], return_counts=True)
    return {"class": int(ids[np.argmax(counts)]), "log10_E": float(np.median(np.log10(e_pa[mine]))),
            "density": float(np.median(rho[mine]))}


def tool_pairs(folder: Path) -> list[tuple[str, Path, Path]]:
    pairs = [(p.name[: -len(f"_{HIGH}.splat")], p.with_name(p.name.replace(f"_{HIGH}.", f"_{LOW}.")), p)
             for p in sorted(folder.glob(f"*_{HIGH}.splat"))]
    return [(name, low, high) for name, low, high in pairs if low.exists()]


def generated_pairs(folder: Path, count: int, seed: int) -> list[tuple[str, Path, Path, float]]:
    """`count` clean objects made at both GENERATED_COUNTS with one seed: (kind, low, high, true median log10 E)."""
    from pixie_gs.cli.main import main
    from pixie_gs.dataset.loader import list_objects, load_object

    for n in GENERATED_COUNTS:
        assert main(["generate", str(folder / str(n)), "--count", str(count), "--split", "test", "--seed", str(seed),
                     "--gaussians", str(n), "--clean", "-q"]) == 0
    lows, highs = (list_objects(folder / str(n), "test") for n in GENERATED_COUNTS)
    out = []
    for low, high in zip(lows, highs):
        cloud, meta = load_object(high)
        out.append((meta["class"], low, high, float(np.median(np.log10(cloud.get_materials()[1])))))
    return out


def compare(pairs, checkpoint: str | None) -> dict:
    from pixie_gs.splat import read_splat

    rows = []
    for pair in pairs:
        name, low, high = pair[:3]
        a, b = (reading(read_splat(p), checkpoint) for p in (low, high))
        row = {"name": name, "low": a, "high": b, "delta_log10_E": a["log10_E"] - b["log10_E"]}
        if len(pair) > 3:
            row["true_log10_E"] = pair[3]
        rows.append(row)
    d = np.abs([r["delta_log10_E"] for r in rows])
    summary = {"pairs": len(rows), "mean_abs_delta_log10_E": float(d.mean()), "median_abs_delta_log10_E":
               float(np.median(d)), "max_abs_delta_log10_E": float(d.max()),
               "class_flips": sum(r["low"]["class"] != r["high"]["class"] for r in rows)}
    if rows and "true_log10_E" in rows[0]:
        summary["mean_abs_error_log10_E"] = float(np.mean([abs(r[k]["log10_E"] - r["true_log10_E"])
                                                           for r in rows for k in ("low", "high")]))
    return {"summary": summary, "rows": rows}


def main() -> None:
    from pixie_gs.progress import set_quiet

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pairs_dir", help="folder of NAME_10k.splat / NAME_100k.splat (benchmarks/lod_pairs_fetch.sh)")
    ap.add_argument("--checkpoint", action="append", default=[], help="candidate checkpoint (repeatable)")
    ap.add_argument("--generated", type=int, default=29, help="generated control pairs (0: none; default 29)")
    ap.add_argument("--seed", type=int, default=3000, help="seed of the generated pairs (test split)")
    ap.add_argument("--json", default=None, help="also write every figure as JSON")
    args = ap.parse_args()
    set_quiet(True)
    tool = tool_pairs(Path(args.pairs_dir))
    if not tool:
        raise SystemExit(f"{args.pairs_dir}: no NAME_{LOW}.splat / NAME_{HIGH}.splat pairs (benchmarks/lod_pairs_fetch.sh)")
    with tempfile.TemporaryDirectory() as tmp:
        gen = generated_pairs(Path(tmp), args.generated, args.seed) if args.generated else []
        results = {}
        for ck in [None, *args.checkpoint]:
            name = ck or "shipped"
            results[name] = {"tool": compare(tool, ck), **({"generated": compare(gen, ck)} if gen else {})}
            for kind, res in results[name].items():
                s = res["summary"]
                print(f"{name:40s} {kind:9s} {s['pairs']:3d} pairs  |Δ log10 E| mean {s['mean_abs_delta_log10_E']:.2f}"
                      f"  median {s['median_abs_delta_log10_E']:.2f}  max {s['max_abs_delta_log10_E']:.2f}  "
                      f"class flips {s['class_flips']}"
                      + (f"  |error| {s['mean_abs_error_log10_E']:.2f}" if "mean_abs_error_log10_E" in s else ""),
                      flush=True)
    base = results["shipped"]["tool"]["summary"]["mean_abs_delta_log10_E"]
    for name, res in results.items():
        print(f"{name:40s} tool pairs' mean |Δ log10 E| against the shipped: "
              f"{res['tool']['summary']['mean_abs_delta_log10_E'] / base:.2f}×")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
