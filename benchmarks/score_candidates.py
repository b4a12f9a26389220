"""Benchmark (issue 12): read back candidate checkpoints the way stops 47–51 chose among them, in one command.

A GPU run brings back a dozen epoch files and soups; each was scored by hand on the CPU with five commands.
This script runs the same five on every checkpoint given (the shipped one first, as the baseline of the same
run) and prints one row per checkpoint:
- generated held-out objects, unlit and lit (64 test-split objects each, seed 4242, 12,000 Gaussians;
  `pixie evaluate`): per-Gaussian material accuracy and average normalised MSE;
- generated broad-leaved potted plants (`bench_leafy_plants.py --per-plant`): the 16 of seed 4601 that the
  plant checks of stops 47–51 trained on, and 5 of seed 4602 that none trained on: the median share of stem
  Gaussians read softer than 1e7 Pa (stems are labelled 1e9–1e10 Pa; lower is better), the median leaf
  error in decades of E and the mean squared log10 E error over the plants;
- the real development set (`bench_real_set.py`, default flags): checks passed, the checks the shipped
  checkpoint fails, and for each candidate the checks it fails or passes unlike the shipped one;
- with `--second DIR` / `--third DIR` (the published files, as `real_holdout/rh_fetch.sh DIR` and
  `real_third/r3_fetch.sh DIR` lay them out), the second and third real sets the same way.
The sets are made once in WORK (about a minute) and reused; then about 70 s per checkpoint on 2 CPU cores,
and about a minute more per checkpoint for the second and third real sets together.

    python benchmarks/score_candidates.py --work /tmp/sc A.epoch03.pt A.epoch06.pt soup.pt
    python benchmarks/score_candidates.py --work /tmp/sc --skip-real A.epoch03.pt   # without ../shared/real
    python benchmarks/score_candidates.py --work /tmp/sc --second /tmp/rh --third /tmp/r3 soup.pt   # the last gate
    python benchmarks/score_candidates.py --work /tmp/sc --soups A.epoch04.pt B.epoch09.pt   # and mean(r58, each)

`--soups` also scores, after each candidate, the mean of its weights with the shipped one's (`pixie_gs.model.soup
OUT shipped CKPT --stats-from 0`, the grid statistics of the shipped file), written into WORK as soupK_NAME.pt:
the soups stops 36–51 chose among.

The plant and development-set figures are the ones candidates were chosen on (selection figures); the second
and third real sets are the check on things not chosen on (the second was used to choose r58 among 13).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "pixie_gs.cli.main"]
SHIPPED = ROOT / "pixie_gs" / "data" / "checkpoints" / "pixie_default.pt"
HELD_OUT = {"unlit": 0, "lit": 1}  # set name → `generate --lighting`
PLANT_SETS = {"plants16": ("bl16", "train"), "plants5": ("blv", "val")}


def run(cmd: list[str], log: Path) -> None:
    """Run `cmd` in the repository root, its output appended to `log`; stop with its tail on failure."""
    with log.open("a") as out:
        out.write("$ " + " ".join(cmd) + "\n")
        out.flush()
        done = subprocess.run(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    if done.returncode != 0:
        tail = log.read_text().splitlines()[-5:]
        raise SystemExit(f"{' '.join(cmd[:4])} … failed (exit {done.returncode}); last lines of {log}:\n"
                         + "\n".join(tail))


def make_sets(work: Path, log: Path) -> None:
    """The held-out and plant sets in WORK, each made once (a folder with its index is reused)."""
    for name, lighting in HELD_OUT.items():
        if not (work / name / "test" / "index.json").exists():
            run(CLI + ["generate", str(work / name), "--count", "64", "--split", "test", "--seed", "4242",
                       "--gaussians", "12000", "--lighting", str(lighting), "--force", "-q"], log)
    if not (work / "bl16" / "train" / "index.json").exists():  # stop 47's recipe (docs/training.md)
        run(CLI + ["generate", str(work / "bl"), "--count", "420", "--split", "train", "--seed", "4601",
                   "--gaussians", "12000", "--classes", "tree", "--force", "-q"], log)
        run([sys.executable, "scripts/filter_split.py", str(work / "bl"), "train", "broad_leaves"], log)
        run([sys.executable, "scripts/filter_split.py", str(work / "bl"), "train", "--first", "16"], log)
        (work / "bl").rename(work / "bl16")
    if not (work / "blv" / "val" / "index.json").exists():
        run(CLI + ["generate", str(work / "blv"), "--count", "60", "--split", "val", "--seed", "4602",
                   "--gaussians", "12000", "--classes", "tree", "--force", "-q"], log)
        run([sys.executable, "scripts/filter_split.py", str(work / "blv"), "val", "broad_leaves"], log)


def held_out(checkpoint: Path, work: Path, log: Path) -> dict[str, tuple[float, float]]:
    """Set name → (per-Gaussian accuracy, average normalised MSE) of `pixie evaluate`."""
    out = {}
    for name in HELD_OUT:
        js = work / f"eval_{name}_{checkpoint.stem}.json"
        run(CLI + ["evaluate", str(checkpoint), str(work / name), "--split", "test", "--device", "cpu", "-q",
                   "--json", str(js)], log)
        g = json.loads(js.read_text())["gaussian"]
        out[name] = (g["accuracy"], g["mse_avg"])
    return out


def plants(checkpoints: list[Path], work: Path, log: Path) -> dict[str, dict[str, tuple[float, float, float]]]:
    """Set name → checkpoint path → (median stems read soft, median leaf error (decades), mean log10 E MSE)."""
    import numpy as np

    out = {}
    for name, (folder, split) in PLANT_SETS.items():
        js = work / f"{name}.json"
        run([sys.executable, "benchmarks/bench_leafy_plants.py", "--split-dir", str(work / folder / split),
             "--per-group", "16", "--per-plant", "--json", str(js), "--checkpoint"] + [str(c) for c in checkpoints],
            log)
        results = json.loads(js.read_text())["results"]
        out[name] = {}
        for c in checkpoints:
            rows = [p for group in results[str(c)].values() for p in group.get("plants", [])]
            out[name][str(c)] = (float(np.median([p["stems_read_soft"] for p in rows])),
                                 float(np.median([p["leaf_median_log10_error"] for p in rows])),
                                 float(np.mean([p["log10_E_mse"] for p in rows])))
    return out


REAL_SETS = {"real": None, "second": ROOT / "benchmarks" / "real_holdout", "third": ROOT / "benchmarks" / "real_third"}


def real_set(checkpoints: list[Path], work: Path, log: Path, name: str = "real",
             orig: Path | None = None) -> dict[str, tuple[int, int, list[str]]]:
    """Checkpoint path → (checks passed, checks, failed checks) on real set `name` (REAL_SETS; the
    development set in ../shared/real by default), its published files in `orig` for the other two."""
    js = work / f"{name}.json"
    cmd = [sys.executable, "benchmarks/bench_real_set.py", "--work", str(work / name), "--json", str(js)]
    if REAL_SETS[name] is not None:
        cmd += ["--real", str(REAL_SETS[name]), "--orig", str(orig)]
    for c in checkpoints[1:]:  # bench_real_set.py scores the shipped checkpoint first by itself
        cmd += ["--checkpoint", str(c)]
    run(cmd, log)
    out = {}
    for c, r in zip(checkpoints, json.loads(js.read_text())):
        failed = [f"{asset.removesuffix('.ply')}: {check['region']}" for asset, a in r["per_asset"].items()
                  for check in a["per_check"] if not check["passed"]]
        out[str(c)] = (r["checks_passed"], r["checks"], failed)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint", nargs="+", type=Path, help="candidate checkpoints (the shipped one is added first)")
    ap.add_argument("--work", type=Path, required=True, help="folder for the sets and every tool's output (reused)")
    ap.add_argument("--skip-real", action="store_true", help="leave out the real development set (../shared/real)")
    ap.add_argument("--soups", action="store_true",
                    help="also score the mean of each candidate's weights with the shipped one's (WORK/soupK_NAME.pt)")
    ap.add_argument("--second", type=Path, default=None, metavar="DIR",
                    help="also the second real set, its files as benchmarks/real_holdout/rh_fetch.sh DIR writes them")
    ap.add_argument("--third", type=Path, default=None, metavar="DIR",
                    help="also the third real set, its files as benchmarks/real_third/r3_fetch.sh DIR writes them")
    ap.add_argument("--json", type=Path, default=None, help="also write every figure as JSON")
    args = ap.parse_args()
    for c in args.checkpoint:
        if not c.is_file():
            raise SystemExit(f"{c}: no such checkpoint")
    others = {name: d for name, d in (("second", args.second), ("third", args.third)) if d is not None}
    for name, d in others.items():
        if not d.is_dir():
            raise SystemExit(f"--{name} {d}: no such folder (make it with the set's fetch script)")
    candidates = [c.resolve() for c in args.checkpoint if c.resolve() != SHIPPED.resolve()]
    args.work.mkdir(parents=True, exist_ok=True)
    log = args.work / "log.txt"
    checkpoints = [SHIPPED]
    for k, c in enumerate(candidates, 1):
        checkpoints.append(c)
        if args.soups:  # numbered: candidates of one name from two runs' folders get a soup each
            soup = args.work / f"soup{k}_{c.stem}.pt"
            run([sys.executable, "-m", "pixie_gs.model.soup", str(soup), str(SHIPPED), str(c), "--stats-from", "0"],
                log)
            checkpoints.append(soup)
    t0 = time.perf_counter()
    make_sets(args.work, log)
    print(f"sets ready in {args.work} ({time.perf_counter() - t0:.0f} s); tools' output in {log}", flush=True)
    rows = {str(c): {"held_out": held_out(c, args.work, log)} for c in checkpoints}
    print(f"held-out sets scored ({time.perf_counter() - t0:.0f} s)", flush=True)
    for name, per in plants(checkpoints, args.work, log).items():
        for c, figures in per.items():
            rows[c][name] = figures
    print(f"plant sets scored ({time.perf_counter() - t0:.0f} s)", flush=True)
    real_sets = ([] if args.skip_real else ["real"]) + list(others)
    for name in real_sets:
        for c, figures in real_set(checkpoints, args.work, log, name, others.get(name)).items():
            rows[c][name] = figures
        print(f"{name} set scored ({time.perf_counter() - t0:.0f} s)", flush=True)
    print(f"\n{'checkpoint':<28}{'unlit acc / MSE':>17}{'lit acc / MSE':>17}"
          f"{'plants16 stems soft / leaf err / MSE':>38}{'plants5 (unseen)':>22}"
          + "".join(f"{name:>8}" for name in real_sets))
    for c, r in rows.items():
        name = "shipped" if c == str(SHIPPED) else Path(c).name
        cells = [f"{r['held_out'][s][0]:.3f} / {r['held_out'][s][1]:.3f}" for s in HELD_OUT]
        cells += ["{:.2f} / {:+.2f} / {:.2f}".format(*r[s]) for s in PLANT_SETS]
        real = "".join(f"{f'{r[s][0]}/{r[s][1]}':>8}" for s in real_sets)
        print(f"{name[:27]:<28}{cells[0]:>17}{cells[1]:>17}{cells[2]:>38}{cells[3]:>22}{real}")
        for s in real_sets:  # the shipped checkpoint's failures; for a candidate, only what differs from them
            mine, base = set(r[s][2]), set(rows[str(SHIPPED)][s][2])
            if c == str(SHIPPED):
                lines = [f"fails ({s}) {f}" for f in r[s][2]]
            else:
                lines = [f"fails ({s}) {f}" for f in r[s][2] if f not in base] + \
                    [f"passes ({s}) {f}" for f in rows[str(SHIPPED)][s][2] if f not in mine]
            for line in lines:
                print(f"{'':<30}{line}")
    print(f"({time.perf_counter() - t0:.0f} s)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
