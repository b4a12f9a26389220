"""Benchmark (issue 12): the real development set, scored for a candidate checkpoint and the shipped one.

The real assets in ../shared/real were made by no one in this project (captures and meshes; PROVENANCE.txt
there), so this is the one material benchmark whose expected answers the model's own code did not produce.
Each asset goes through the commands a user runs, with default flags: glTF meshes through
`pixie convert X.glb X.ply`, then `pixie annotate IN OUT` (prepare included), then the set's own scorer
`score.py expectations.json OUT`. The baseline is the shipped checkpoint, annotated in the same run; the
report gives both scores per asset, the checks each one fails, and per check the share of the region's
Gaussians that satisfies it beside the share asked (how close a pass is to a fail). No speed target.
`--crop-to-object-box` annotates every asset with `--crop box:…` of its expectations.json object box instead,
what a user who draws a box around the object runs: a reading that passes only with the default grid is a
near tie (docs/model_card.md, "Candidates r51 and r52": the redplant's foliage).

    python benchmarks/bench_real_set.py                                  # the shipped checkpoint alone (~40 s)
    python benchmarks/bench_real_set.py --checkpoint cand.pt             # a candidate beside the shipped one
    python benchmarks/bench_real_set.py --checkpoint a.pt --checkpoint b.pt --json real.json
    python benchmarks/bench_real_set.py --crop-to-object-box                 # each asset cropped to its box
    python benchmarks/bench_real_set.py --crop-to-object-box --box-scale 1.5 # … to its box grown 1.5×

Needs ../shared/real (not part of a user's clone); `--real DIR` points elsewhere. The second real set,
benchmarks/real_holdout (expectations written from what each object is made of, before any checkpoint ran on
it; README there), keeps only its expectations and provenance in the repository; its published files go in a
folder of your own, and the development set's scorer scores it:

    python benchmarks/bench_real_set.py --real benchmarks/real_holdout --orig DIR --scorer ../shared/real/score.py
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pixie_gs.model.metrics import separation_auroc

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "pixie_gs" / "data" / "checkpoints" / "pixie_default.pt"
CLI = [sys.executable, "-m", "pixie_gs.cli.main"]
ASSET_LINE = re.compile(r"^(?P<file>\S+): (?P<ok>\d+)/(?P<n>\d+) ")
CHECK = re.compile(r"\[(?P<verdict>ok|FAIL)\] (?P<region>.+?): (?P<share>[\d.]+) of \d+ \(need (?P<need>[\d.]+)\)")
SUMMARY_LINE = re.compile(r"real plausibility: (\d+) of (\d+) checks, (\d+) of (\d+) assets")


def source_for(entry_file: str, orig: Path) -> tuple[Path, bool]:
    """(published file behind an expectations entry, whether it is a mesh to convert first)."""
    stem = Path(entry_file).stem
    for candidate, mesh in ((orig / f"{stem}.glb", True), (orig / f"{stem}.gltf", True),
                            (orig / stem / f"{stem}.gltf", True), (orig / entry_file, False),
                            (orig / f"{stem}.compressed.ply", False), (orig / f"{stem}.splat", False),
                            (orig / f"{stem}.spz", False)):
        if candidate.exists():
            return candidate, mesh
    raise SystemExit(f"{orig}: no published file for expectations entry '{entry_file}'")


def run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["(no output)"]
        raise SystemExit(f"command failed ({done.returncode}): {' '.join(cmd[2:])}: {last[0]}")


def expectation_entries(real: Path) -> list[dict]:
    """The entries of the set's expectations.json (one per asset)."""
    return json.loads((real / "expectations.json").read_text())


def inputs(real: Path, orig: Path, work: Path) -> dict[str, Path]:
    """Expectations file name → splat `pixie annotate` reads (meshes converted once, default flags)."""
    out = {}
    for entry in expectation_entries(real):
        src, mesh = source_for(entry["file"], orig)
        if mesh:
            converted = work / "inputs" / entry["file"]
            converted.parent.mkdir(parents=True, exist_ok=True)
            run(CLI + ["convert", str(src), str(converted), "-q", "--force"])
            src = converted
        out[entry["file"]] = src
    return out


def object_box_crops(real: Path, scale: float = 1.0) -> dict[str, list[str]]:
    """Expectations file name → the `--crop box:x0,y0,z0,x1,y1,z1` arguments of its object box (file units),
    grown `scale`× about its centre (1: the box as written)."""
    crops = {}
    for e in expectation_entries(real):
        if "object_box" not in e:
            continue
        lo, hi = (np.asarray(c, dtype=float) for c in e["object_box"])
        centre, half = (lo + hi) / 2, scale * (hi - lo) / 2
        crops[e["file"]] = ["--crop", "box:" + ",".join(f"{v:.6g}" for v in np.concatenate([centre - half, centre + half]))]
    return crops


def region_readings(real: Path, out_dir: Path) -> dict[str, list[dict[str, float]]]:
    """Expectations file name → per check, what annotate wrote for the Gaussians inside the check's box
    (inclusive, as score.py selects them): mean `confidence`, median log10 E (Pa) and median density (kg/m³);
    NaN for an empty box. The medians show a drift (wood read softer) before a check's share falls."""
    from pixie_gs.splat import read_splat

    out = {}
    for entry in expectation_entries(real):
        cloud = read_splat(out_dir / entry["file"])
        xyz = np.asarray(cloud.means, float)
        fields = {"confidence": (np.asarray(cloud.get("confidence"), float), np.mean),  # each with its statistic
                  "log10_E_pa": (np.log10(np.asarray(cloud.get("E"), float)), np.median),
                  "density_kg_m3": (np.asarray(cloud.get("density"), float), np.median)}
        readings = []
        for region in entry["regions"]:
            lo, hi = (np.asarray(c, float) for c in region["box"])
            inside = np.all((xyz >= lo) & (xyz <= hi), axis=1)
            readings.append({key: float(statistic(values[inside])) if inside.any() else float("nan")
                             for key, (values, statistic) in fields.items()})
        out[entry["file"]] = readings
    return out


def pass_fail_auroc(passed: list[bool], confidence: list[float]) -> float | None:
    """Probability that a passed check has a higher mean confidence than a failed one (ties ½); None when
    all checks passed or all failed."""
    good = [c for p, c in zip(passed, confidence) if p]
    bad = [c for p, c in zip(passed, confidence) if not p]
    if not good or not bad:
        return None
    return separation_auroc(good, bad)


def draw_picture(real: Path, result: dict, out_dir: Path, path: Path, per_row: int = 4) -> None:
    """One picture of a checkpoint's annotations: per asset its colours beside its log10 E (viridis over the
    dataset range, pixie_gs.viz.log_e_colors), seen from the side (the expectations' up drawn upwards), with
    the checks passed in the title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pixie_gs.splat import read_splat
    from pixie_gs.viz import log_e_colors

    entries = expectation_entries(real)
    rows = -(-len(entries) // per_row)
    fig, axes = plt.subplots(rows, 2 * per_row, figsize=(4.2 * per_row, 2.6 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.set_axis_off()
    rng = np.random.default_rng(0)
    for k, entry in enumerate(entries):
        cloud = read_splat(out_dir / entry["file"])
        E = np.asarray(cloud.get("E"), float)
        up = np.asarray(entry["up"], float) / np.linalg.norm(entry["up"])
        side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side)
        pick = rng.choice(len(E), min(len(E), 25_000), replace=False)
        depth = np.cross(side, up)
        pick = pick[np.argsort(cloud.means[pick] @ depth)]  # far Gaussians first, near ones drawn over them
        xy = np.stack([cloud.means[pick] @ side, cloud.means[pick] @ up], 1)
        mine = result["per_asset"].get(entry["file"], {})
        title = f"{entry['file'][:-4][:22]}: {mine.get('passed', 0)}/{len(entry['regions'])}"
        for j, colours in enumerate((np.clip(cloud.rgb()[pick], 0, 1), log_e_colors(E[pick]))):
            ax = axes[k // per_row, 2 * (k % per_row) + j]
            ax.scatter(xy[:, 0], xy[:, 1], s=0.4, c=colours, linewidths=0)
            ax.set_aspect("equal")
            ax.set_title(title if j == 0 else "log10 E: 3 (purple) – 11 (yellow) Pa", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=60)
    plt.close(fig)


def score(real: Path, scorer: Path, files: dict[str, Path], checkpoint: Path, out_dir: Path,
          extra: dict[str, list[str]] | None = None) -> dict:
    """Annotate every asset with `checkpoint` (default flags, plus `extra[name]`) into `out_dir` and score it."""
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    for name, src in files.items():
        run(CLI + ["annotate", str(src), str(out_dir / name), "--device", "cpu", "--checkpoint", str(checkpoint),
                   "-q", "--force"] + (extra or {}).get(name, []))
    seconds = time.perf_counter() - t0
    done = subprocess.run([sys.executable, str(scorer), str(real / "expectations.json"), str(out_dir)],
                          capture_output=True, text=True)
    if done.returncode != 0 and "real plausibility" not in done.stdout:
        raise SystemExit(f"score.py failed: {(done.stderr or done.stdout).strip()[-300:]}")
    assets, summary = {}, None
    for line in done.stdout.splitlines():
        m = ASSET_LINE.match(line)
        if m:
            checks = [{"region": c["region"].strip(), "passed": c["verdict"] == "ok", "share": float(c["share"]),
                       "need": float(c["need"])} for c in CHECK.finditer(line)]
            assets[m["file"]] = {"passed": int(m["ok"]), "checks": int(m["n"]), "per_check": checks,
                                 "failed": [c["region"] for c in checks if not c["passed"]]}
        s = SUMMARY_LINE.search(line)
        if s:
            summary = tuple(int(v) for v in s.groups())
    if summary is None:
        raise SystemExit(f"score.py printed no summary line for {checkpoint}")
    for name, readings in region_readings(real, out_dir).items():
        for check, reading in zip(assets.get(name, {}).get("per_check", []), readings):
            check.update(reading)
    checks = [c for a in assets.values() for c in a["per_check"]]
    auroc = pass_fail_auroc([c["passed"] for c in checks], [c.get("confidence", float("nan")) for c in checks])
    return {"checkpoint": str(checkpoint), "checks_passed": summary[0], "checks": summary[1],
            "assets_plausible": summary[2], "assets": summary[3], "annotate_s": round(seconds, 1),
            "confidence_auroc": auroc, "per_asset": assets}


def print_check_table(results: list[dict], key: str, lead) -> None:
    """One line per check of the shipped checkpoint's assets: `lead(check)` (10 characters), then per checkpoint
    the check's `key` figure, marked ✗ where that checkpoint failed it ('-' where it has no such check)."""
    base = results[0]
    for name, asset in base["per_asset"].items():
        for k, check in enumerate(asset["per_check"]):
            cells = []
            for r in results:
                mine = r["per_asset"].get(name, {}).get("per_check", [])
                cells.append(f"{mine[k].get(key, float('nan')):.3f}{'' if mine[k]['passed'] else '✗'}"
                             if k < len(mine) else "-")
            print(f"  {name[:-4] + ': ' + check['region']:52s} {lead(check):10s} " + "  ".join(f"{c:>7s}" for c in cells))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", action="append", default=[], help="candidate checkpoint (repeatable)")
    ap.add_argument("--real", default=str(ROOT.parent / "shared" / "real"), help="the real development set folder")
    ap.add_argument("--orig", default=None, help="folder of the set's published files (default: REAL/orig)")
    ap.add_argument("--scorer", default=None,
                    help="score.py to use (default: REAL/score.py, else ../shared/real/score.py)")
    ap.add_argument("--work", default=None, help="folder for converted inputs and annotations (default: a temp dir)")
    ap.add_argument("--json", default=None, help="also write every figure as JSON")
    ap.add_argument("--picture", default=None,
                    help="also draw the shipped checkpoint's annotations (colour and log10 E per asset) to this PNG")
    ap.add_argument("--crop-to-object-box", action="store_true",
                    help="annotate each asset cropped to its expectations.json object box (default: no crop)")
    ap.add_argument("--box-scale", type=float, default=1.0,
                    help="with --crop-to-object-box: grow each box this many times about its centre (default 1)")
    args = ap.parse_args()
    real = Path(args.real)
    if not (real / "expectations.json").exists():
        raise SystemExit(f"{real}: no expectations.json (the real development set lives in ../shared/real)")
    orig = Path(args.orig) if args.orig else real / "orig"
    scorer = Path(args.scorer) if args.scorer else next(
        (p for p in (real / "score.py", ROOT.parent / "shared" / "real" / "score.py") if p.exists()), real / "score.py")
    if not scorer.exists():
        raise SystemExit(f"{scorer}: no scorer (give --scorer PATH to the real set's score.py)")
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="pixie_real_"))
    files = inputs(real, orig, work)
    checkpoints = [SHIPPED] + [Path(c) for c in args.checkpoint if Path(c).resolve() != SHIPPED.resolve()]
    crops = object_box_crops(real, args.box_scale) if args.crop_to_object_box else None
    results = []
    for k, ck in enumerate(checkpoints):
        label = "shipped" if k == 0 else f"candidate{k}"
        r = score(real, scorer, files, ck, work / label, crops)
        r["label"] = label
        results.append(r)
        print(f"{label:10s} {ck.name:24s} {r['checks_passed']:2d} of {r['checks']} checks, "
              f"{r['assets_plausible']} of {r['assets']} assets plausible  (annotate {r['annotate_s']:.0f} s)")
    base = results[0]
    if args.picture:
        draw_picture(real, base, work / base["label"], Path(args.picture))
    names = list(base["per_asset"])
    print("\nper asset (checks passed)   " + "  ".join(f"{r['label']:>10s}" for r in results))
    for name in names:
        cells = "  ".join(f"{r['per_asset'].get(name, {}).get('passed', 0)}/{base['per_asset'][name]['checks']}"
                          .rjust(10) for r in results)
        print(f"  {name:25s} {cells}")
    print("\nshare of each region's Gaussians that satisfies its check (need), per checkpoint; a pass by a few "
          "points is one small change away from a fail")
    print_check_table(results, "share", lambda check: f"need {check['need']:.2f}")
    print("\nmean confidence annotate wrote in each check's box, per checkpoint (✗: the check failed); AUROC: how "
          "often a passed check is more confident than a failed one (0.5: confidence says nothing about failure)")
    print_check_table(results, "confidence", lambda check: "")
    print(f"  {'AUROC (passed vs failed checks)':52s}            " + "  ".join(
        f"{'-' if r['confidence_auroc'] is None else format(r['confidence_auroc'], '.3f'):>7s}" for r in results))
    for r in results:
        fails = [f"{n}: {', '.join(a['failed'])}" for n, a in r["per_asset"].items() if a["failed"]]
        print(f"{r['label']} fails: " + ("; ".join(fails) if fails else "nothing"))
    for r in results[1:]:
        print(f"{r['label']} vs shipped: {r['checks_passed'] - base['checks_passed']:+d} checks "
              f"({r['checks_passed']}/{r['checks']} against {base['checks_passed']}/{base['checks']})")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
