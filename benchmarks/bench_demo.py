"""Time `pixie demo` end to end (target: under 2 minutes on a 2-core CPU).

Runs the command as a user does (`python -m pixie_gs demo`) in subprocesses:
  cold  — a fresh, empty Warp kernel cache (what the first run after `pip install` pays),
  warm  — the same again with that cache filled,
and, as the baseline in the same run, the bare start-up every run pays: a Python that imports
pixie_gs.demo, torch, warp and rerun and initialises Warp. Prints wall seconds, CPU seconds
(user + sys of the child) and peak RSS for each, the demo's own per-stage split, and the ratio
of each demo run to the baseline and to the 120 s target.

    python benchmarks/bench_demo.py [--device cpu] [--frames 30]
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_S = 120.0
BASELINE_CODE = "import pixie_gs.demo, torch, warp, rerun; warp.config.quiet = True; warp.init()"


def timed(cmd: list[str], env: dict[str, str]) -> tuple[float, float, float, str]:
    """(wall s, CPU s, peak RSS MB, stderr) of one child process (its own rusage, via wait4)."""
    with tempfile.TemporaryFile("w+") as err:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        stderr = err.read()
    if proc.returncode != 0:
        sys.exit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{stderr[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, stderr


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--frames", type=int, default=30)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_demo_") as tmp:
        env = dict(os.environ, WARP_CACHE_PATH=str(Path(tmp) / "warp_cache"))
        rows = [("baseline: start-up (imports + warp.init)", *timed([sys.executable, "-c", BASELINE_CODE], env))]
        demo = [sys.executable, "-m", "pixie_gs", "demo", "--device", args.device, "--frames", str(args.frames)]
        for label in ("pixie demo, cold Warp kernel cache", "pixie demo, warm Warp kernel cache"):
            rows.append((label, *timed(demo + ["--out", str(Path(tmp) / "out")], env)))
    base_wall = rows[0][1]
    print(f"{'run':<42} {'wall s':>7} {'CPU s':>7} {'peak RSS MB':>12} {'÷ baseline':>11} {'÷ 120 s':>8}")
    for label, wall, cpu, rss, _ in rows:
        print(f"{label:<42} {wall:7.1f} {cpu:7.1f} {rss:12.0f} {wall / base_wall:11.1f} {wall / TARGET_S:8.2f}")
    for label, *_, err in rows[1:]:
        done = re.search(r"done in .*", err)
        print(f"{label}: {done.group(0) if done else '(no stage summary)'}")
    print(f"load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
