"""Dataset generation: throughput (objects/s) and the full label audit over a 200-object split.

Prints: objects/s with K workers for COUNT objects at ~G Gaussians each, objects/s of one worker
on a subset measured in the same run (baseline) and their ratio; then audits every object: labels
inside the class ranges, every constraint satisfied, per-Gaussian values equal to the record,
per-class counts within ±10 % of the mean, and all classes present.

usage: python benchmarks/bench_generate.py [--count 200] [--gaussians 50000] [--workers 2]
       [--baseline-count 20] [--keep DIR]
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from pixie_gs.dataset.generate import generate_split
from pixie_gs.dataset.labels import check_object_labels, load_class_table
from pixie_gs.dataset.loader import list_objects, load_object
from pixie_gs.progress import set_quiet


def audit(data_dir: Path) -> tuple[int, list[str], Counter]:
    """(objects checked, problems, class counts) over every object of the train split."""
    table = load_class_table()
    problems: list[str] = []
    counts: Counter = Counter()
    paths = list_objects(data_dir, "train")
    for path in paths:
        cloud, meta = load_object(path)
        spec = table[meta["class"]]
        counts[meta["class"]] += 1
        material_id, E, nu, rho = cloud.get_materials()
        part_id = cloud.get("part_id")
        values = {}
        for part in meta["parts"]:
            sel = part_id == part["part_id"]
            v = {"E": np.unique(E[sel]), "nu": np.unique(nu[sel]), "density": np.unique(rho[sel]),
                 "material_id": np.unique(material_id[sel])}
            if any(len(a) != 1 for a in v.values()) or not sel.any():
                problems.append(f"{path.name}: part {part['name']} values not constant or empty")
                continue
            values[part["name"]] = {k: float(a[0]) if k != "material_id" else int(a[0]) for k, a in v.items()}
            if values[part["name"]]["E"] != part["E"]:
                problems.append(f"{path.name}: part {part['name']} E differs from its record")
        problems += [f"{path.name}: {p}" for p in check_object_labels(spec, values)]
        if int(sum(p["count"] for p in meta["parts"])) != len(cloud):
            problems.append(f"{path.name}: part counts do not add up")
    return len(paths), problems, counts


def _cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children (the pool workers)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=200)
    ap.add_argument("--gaussians", type=int, default=50_000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--baseline-count", type=int, default=20)
    ap.add_argument("--keep", default=None, help="keep the generated dataset here (default: temp, removed)")
    args = ap.parse_args()
    set_quiet(True)
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_generate_"))
    try:
        t0 = time.perf_counter()
        generate_split(root / "base", args.baseline_count, seed=1, workers=1, n_gaussians=args.gaussians,
                       force=True)
        base_rate = args.baseline_count / (time.perf_counter() - t0)
        cpu0 = _cpu_seconds()
        t0 = time.perf_counter()
        split = generate_split(root / "full", args.count, seed=0, workers=args.workers,
                               n_gaussians=args.gaussians, force=True)
        elapsed = time.perf_counter() - t0
        cpu = _cpu_seconds() - cpu0
        rate = args.count / elapsed
        size_mb = sum(p.stat().st_size for p in split.iterdir()) / 1e6
        gaussians = sum(load_object(p)[1]["gaussians"] for p in list_objects(root / "full", "train"))
        print(f"generate: {args.count} objects, {gaussians / args.count:,.0f} Gaussians/object on average, "
              f"{args.workers} workers: {elapsed:.1f} s = {rate:.2f} objects/s "
              f"({size_mb:.0f} MB written, {size_mb / args.count:.2f} MB/object)")
        print(f"cpu: {cpu:.1f} CPU s in all processes = {cpu / args.count:.3f} CPU s/object "
              f"(load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; an idle 2-core machine "
              f"would reach ~{2 * args.count / cpu:.1f} objects/s)")
        print(f"baseline: 1 worker, {args.baseline_count} objects: {base_rate:.2f} objects/s; "
              f"ratio {rate / base_rate:.2f}x")
        print(f"target >= 2 objects/s: {'PASS' if rate >= 2.0 else 'FAIL'}")
        t0 = time.perf_counter()
        n, problems, counts = audit(root / "full")
        mean = n / len(counts)
        spread = max(abs(c - mean) / mean for c in counts.values())
        all_classes = set(counts) == set(load_class_table())
        print(f"audit: {n} objects checked in {time.perf_counter() - t0:.1f} s, {len(problems)} label problems")
        for p in problems[:20]:
            print(f"  {p}")
        print(f"classes: {dict(sorted(counts.items()))}; max deviation from mean {spread * 100:.1f} % "
              f"({'PASS' if spread <= 0.10 else 'FAIL'} ±10 %); all ten classes: {all_classes}")
        ok = not problems and spread <= 0.10 and all_classes
        return 0 if ok else 1
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
