"""Which generated categories pull each real-capture reading, and which way (pixie_gs/model/attribution.py).

For every check of the real development set (../shared/real/expectations.json) it takes the checkpoint's
reading there (mean normalised log E, and log ρ where the check has a density range, over the region's
Gaussians; the asset cropped to its object box and turned by the up a person reads), and for every object
of a generated train split the gradient of the training loss. It prints, per category, the mean cosine
between a descent step on that category's objects and each reading's gradient: > 0 means fine-tuning on
that category raises the reading (stiffer, denser), < 0 lowers it; and, per reading, the net pull of the
whole set and the categories that pull most either way. A diagnostic for choosing a data mix before a GPU
run; first order at one checkpoint, so it says where a fine-tune starts to go, not where it ends.

    python scripts/real_reading_attribution.py                       # shipped checkpoint, 2 objects per category (~4 min)
    python scripts/real_reading_attribution.py --checkpoint c.pt --per-class 3 --json attr.json
    python scripts/real_reading_attribution.py --data DIR            # objects of DIR/train (pixie generate)

Needs ../shared/real (not in a user's clone); `--real DIR` points elsewhere.
"""
from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_real_set import CLI, expectation_entries, inputs, run  # noqa: E402  (one way to turn the set's files into splats)

from pixie_gs.model.attribution import loss_gradient, reading_gradient, step_cosine  # noqa: E402
from pixie_gs.model.checkpoint import load_checkpoint  # noqa: E402
from pixie_gs.model.data import DeviceStore, load_split  # noqa: E402
from pixie_gs.progress import progress, set_quiet  # noqa: E402
from pixie_gs.splat import read_splat  # noqa: E402


def real_readings(loaded, real: Path, work: Path) -> list[dict]:
    """Every (check, quantity) reading of the set: its name, value and gradient."""
    files = inputs(real, real / "orig", work)
    readings = []
    for entry in expectation_entries(real):
        cloud = read_splat(files[entry["file"]])
        lo, hi = np.asarray(entry["object_box"], float)
        cloud = cloud.subset(np.all((cloud.means >= lo) & (cloud.means <= hi), axis=1))
        for region in entry["regions"]:
            rlo, rhi = np.asarray(region["box"], float)
            inside = np.all((cloud.means >= rlo) & (cloud.means <= rhi), axis=1)
            if not inside.any():  # a region outside the object box (a ground plane): the crop holds none of it
                print(f"skipped {entry['file']}: {region['region']} (none of its Gaussians inside the object box)")
                continue
            quantities = ["log_E"] + (["log_rho"] if "density_range" in region["expect"] else [])
            for q in quantities:
                value, grad = reading_gradient(loaded, cloud, np.asarray(entry["up"], float), inside, q)
                name = f"{Path(entry['file']).stem}: {region['region']} ({q})"
                readings.append({"name": name, "value": value, "grad": grad})
    return readings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default=None, help="checkpoint (default: the shipped one)")
    ap.add_argument("--real", default=str(ROOT.parent / "shared" / "real"), help="the real development set folder")
    ap.add_argument("--data", default=None, help="a `pixie generate` folder whose train split to use")
    ap.add_argument("--per-class", type=int, default=2, help="without --data: capture-like objects per category")
    ap.add_argument("--gaussians", type=int, default=8000, help="without --data: Gaussians per object")
    ap.add_argument("--seed", type=int, default=2960, help="without --data: dataset seed")
    ap.add_argument("--json", default=None, help="also write every cosine as JSON")
    args = ap.parse_args()
    real = Path(args.real)
    if not (real / "expectations.json").exists():
        raise SystemExit(f"{real}: no expectations.json (the real development set lives in ../shared/real)")
    t0 = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix="pixie_attr_"))
    data = Path(args.data) if args.data else work / "data"
    if not args.data:
        from pixie_gs.dataset.labels import load_class_table

        count = args.per_class * len(load_class_table())
        run(CLI + ["generate", str(data), "--count", str(count), "--split", "train", "--seed", str(args.seed),
                   "--gaussians", str(args.gaussians), "-q"])
    loaded = load_checkpoint(args.checkpoint, "cpu")
    set_quiet(True)
    readings = real_readings(loaded, real, work)
    records, _ = load_split(data, "train", list(loaded.features.extra_names))
    categories = [r.class_name or r.name for r in records]
    store = DeviceStore(records, "cpu")
    rows = []
    set_quiet(False)
    for i in progress(range(len(store)), "objects", total=len(store), unit="object"):
        g = loss_gradient(loaded, store, [i])
        rows.append({"category": categories[i], "cos": [step_cosine(r["grad"], g) for r in readings],
                     "dot": [float(-(r["grad"] @ g)) for r in readings]})
    by_cat = collections.defaultdict(list)
    for row in rows:
        by_cat[row["category"]].append(row)
    short = [r["name"] for r in readings]
    print(f"checkpoint {loaded.path}; "
          f"{len(rows)} objects of {len(by_cat)} categories; {len(readings)} readings ({time.perf_counter() - t0:.0f} s)")
    print("readings (normalised units, [-1, 1]):")
    for k, r in enumerate(readings):
        print(f"  R{k:<2d} {r['value']:+.3f}  {r['name']}")
    print("\nmean cosine of a descent step on the category with each reading's gradient (> 0: raises it)")
    print(f"  {'category':18s} " + " ".join(f"{'R' + str(k):>6s}" for k in range(len(readings))))
    for cat in sorted(by_cat):
        cos = np.mean([row["cos"] for row in by_cat[cat]], axis=0)
        print(f"  {cat:18s} " + " ".join(f"{c:+6.2f}" for c in cos))
    print("\nper reading: net pull of the whole set (sum of first-order changes over the sum of their sizes) and "
          "the categories that pull most")
    for k, name in enumerate(short):
        total = sum(abs(row["dot"][k]) for row in rows) or 1.0
        share = collections.Counter()
        for row in rows:
            share[row["category"]] += row["dot"][k] / total
        ranked = share.most_common()
        up = ", ".join(f"{c} {v:+.2f}" for c, v in ranked[:3] if v > 0)
        down = ", ".join(f"{c} {v:+.2f}" for c, v in reversed(ranked[-3:]) if v < 0)
        print(f"  R{k:<2d} net {sum(share.values()):+.2f}  up: {up or '-'}  down: {down or '-'}   {name}")
    if args.json:
        Path(args.json).write_text(json.dumps({"readings": [{"name": r["name"], "value": r["value"]} for r in readings],
                                               "objects": rows}, indent=1))


if __name__ == "__main__":
    main()
