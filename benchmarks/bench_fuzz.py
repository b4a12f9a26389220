"""Benchmark (issue 15): the whole bad-input corpus, mutation fuzzing, and interrupted `simulate --force`.

1. Corpus: every case of tests/fuzz_corpus.py (≥ 300 bad inputs over every command), run in-process
   through `pixie_gs.cli.main.main`; per command: cases, tracebacks, hangs, wrong successes,
   leftovers, modified inputs, other broken promises (wrong exit code, not exactly one error line).
2. Mutation fuzzing: N random mutations of a valid splat of each format (.ply, compressed .ply, .splat,
   .spz) through `pixie info --json` (error in one line, or a validated splat with finite covariances), and
   of a mesh of each format trimesh writes (GLB, OBJ, STL, PLY, OFF) through `pixie convert`; and P mutated
   splats and meshes that still make a valid splat through `pixie annotate`, `pixie render` of the result, a
   3-frame `pixie simulate` and `pixie render` of its frames (finite results or one line with exit 1 or 3, never
   a crash; stop 53 found a NaN annotate and a segfaulting simulate this way).
3. Interruption: T trials each of SIGINT, SIGTERM and SIGKILL sent at a random moment of
   `pixie simulate --force` over an existing output (subprocesses, as a user runs it); afterwards
   the output folder must be the old output byte for byte or the complete new one (frames that
   match tracks.npz), never a mix; no staging folder may survive a handled signal, and the one a
   SIGKILLed run leaves is removed by the next run.
4. Memory: peak anonymous memory of `simulate` for 40 vs 400 frames (flat: frames and the
   trajectory stream to disk).

All counts except the outcome split (old/new) must be 0. This is a correctness benchmark (no speed
target, so no baseline); the figures before the change are the issue's (SIGINT deleted the old
frames, SIGKILL left a folder mixing new frames with old tracks, ~40 tracebacks in ~340 bad inputs).

    python benchmarks/bench_fuzz.py                       # corpus + 9×1000 mutations + 20×3 interruptions
    python benchmarks/bench_fuzz.py --mutations 200 --trials 3   # quick look
    python benchmarks/bench_fuzz.py --skip corpus,memory --seed 5301   # new mutations and moments
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import io
import json
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import fuzz_corpus as fc  # noqa: E402

CATEGORIES = ("tracebacks", "hangs", "wrong successes", "leftovers", "modified inputs", "other")


def categorise(problems: list[str]) -> collections.Counter:
    c: collections.Counter = collections.Counter()
    for p in problems:
        if p.startswith("traceback"):
            c["tracebacks"] += 1
        elif p == "hang":
            c["hangs"] += 1
        elif p.startswith("wrong success"):
            c["wrong successes"] += 1
        elif p.startswith("leftovers"):
            c["leftovers"] += 1
        elif p.startswith("modified inputs"):
            c["modified inputs"] += 1
        else:
            c["other"] += 1
    return c


def print_table(title: str, rows: dict[str, collections.Counter], counts: dict[str, int]) -> None:
    print(f"\n{title}")
    print(f"{'command':10s} {'cases':>6s} " + " ".join(f"{c:>15s}" for c in CATEGORIES))
    total = collections.Counter()
    for cmd in sorted(rows):
        total.update(rows[cmd])
        print(f"{cmd:10s} {counts[cmd]:6d} " + " ".join(f"{rows[cmd][c]:15d}" for c in CATEGORIES))
    print(f"{'all':10s} {sum(counts.values()):6d} " + " ".join(f"{total[c]:15d}" for c in CATEGORIES))


def run_corpus(work: Path, verbose: bool) -> dict:
    cases = fc.corpus(seed=0)
    rows: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    counts: collections.Counter = collections.Counter()
    t0 = time.perf_counter()
    for i, case in enumerate(cases):
        outcome = fc.run_case(case, work / f"case{i:04d}", timeout_s=120)
        counts[case.command] += 1
        rows[case.command].update(categorise(outcome.problems))
        if outcome.problems and verbose:
            print(f"  {case.command} {case.name}: {outcome.problems}", flush=True)
        shutil.rmtree(work / f"case{i:04d}", ignore_errors=True)
    print_table(f"bad-input corpus: {len(cases)} cases in {time.perf_counter() - t0:.0f} s", rows, counts)
    return {"cases": len(cases), "per_command": {k: {"cases": counts[k], **dict(rows[k])} for k in counts}}


def fuzz_each_format(suffixes: tuple[str, ...], base_of: Callable[[str], bytes],
                     mutate: Callable[[bytes, str, np.random.Generator], bytes],
                     check_once: Callable[[bytes, str], "fc.Outcome"], rng_of: Callable[[int, str], np.random.Generator],
                     what: str, iterations: int, verbose: bool) -> dict:
    """`iterations` files of each format, each its valid base mutated 1–3 times, through `check_once`;
    per format the outcome split and the broken promises (all must be 0)."""
    figures = {}
    for k, suffix in enumerate(suffixes):
        rng, base = rng_of(k, suffix), base_of(suffix)
        tally = collections.Counter()
        outcomes = collections.Counter()
        t0 = time.perf_counter()
        for _ in range(iterations):
            blob = base
            for _ in range(int(rng.integers(1, 4))):
                blob = mutate(blob, suffix, rng)
            outcome = check_once(blob, suffix)
            tally.update(categorise(outcome.problems))
            outcomes["accepted (valid splat)" if outcome.code == 0 else "refused in one line"] += 1
            if outcome.problems and verbose:
                print(f"  mutation of .{suffix}: {outcome.problems}", flush=True)
        print(f"\nmutation fuzzing of {what.format(suffix=suffix)}: {iterations} iterations in "
              f"{time.perf_counter() - t0:.0f} s; " + ", ".join(f"{k} {v}" for k, v in outcomes.items()))
        print("  " + ", ".join(f"{c} {tally[c]}" for c in CATEGORIES))
        figures[suffix] = {"iterations": iterations, **dict(outcomes), **{c: tally[c] for c in CATEGORIES}}
    return figures


def run_mutations(work: Path, iterations: int, verbose: bool, seed: int) -> dict:
    """Each splat format through `pixie info --json`. The .ply rows keep the recorded sequence (a 30-Gaussian
    table with materials, rng `seed`); each other format draws from its own stream (`[seed, k]`) over a
    300-Gaussian file written by pixie's writer."""
    folder = work / "mutations"
    folder.mkdir()
    return fuzz_each_format(
        fc.SPLAT_SUFFIXES,
        lambda suffix: fc.valid_ply_bytes(30, materials=True) if suffix == "ply" else fc.valid_splat_bytes(suffix),
        fc.mutate_splat, lambda blob, suffix: fc.fuzz_info_once(blob, folder, name=f"m.{suffix}"),
        lambda k, suffix: np.random.default_rng(seed if suffix == "ply" else [seed, k]),
        "a valid .{suffix} through `pixie info --json`", iterations, verbose)


def run_mesh_mutations(work: Path, iterations: int, verbose: bool, seed: int) -> dict:
    """Each mesh format trimesh writes (GLB, OBJ, STL, PLY, OFF) through `pixie convert`: an error in one
    line, or a valid 200-Gaussian splat."""
    folder = work / "mesh_mutations"
    folder.mkdir()
    return fuzz_each_format(
        fc.MESH_SUFFIXES_FUZZED, fc.valid_mesh_bytes, fc.mutate_mesh,
        lambda blob, suffix: fc.fuzz_convert_once(blob, suffix, folder),
        lambda k, suffix: np.random.default_rng([seed, 100 + k]),
        "a trimesh-written .{suffix} mesh through `pixie convert`", iterations, verbose)


def _valid_mutated_source(rng: np.random.Generator, splats: dict, meshes: dict, folder: Path) -> tuple[bytes, str] | None:
    """One mutated input of a random format that still makes a valid splat: (its splat bytes, their format), or
    None where the mutation was refused. A mutated mesh is converted first (`pixie convert --count 400`)."""
    from pixie_gs.cli.main import main
    from pixie_gs.splat import read_splat

    formats = list(splats) + list(meshes)
    suffix = formats[int(rng.integers(0, len(formats)))]
    is_mesh = suffix in meshes
    blob = (meshes if is_mesh else splats)[suffix]
    for _ in range(int(rng.integers(1, 4))):
        blob = fc.mutate_mesh(blob, suffix, rng) if is_mesh else fc.mutate_splat(blob, suffix, rng)
    probe, converted = folder / f"probe.{suffix}", folder / "converted.ply"
    probe.write_bytes(blob)
    try:
        if is_mesh:
            with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
                if main(["convert", str(probe), str(converted), "--count", "400", "-q"]) != 0:
                    return None
            return converted.read_bytes(), "ply"
        read_splat(probe).validate()  # quiet as the CLI's: read_splat and invalid_gaussians ignore float warnings
        return blob, suffix
    except Exception:  # noqa: BLE001 - refused inputs are the mutation part's business
        return None
    finally:
        probe.unlink()
        converted.unlink(missing_ok=True)


def run_pipeline(work: Path, count: int, verbose: bool, seed: int) -> dict:
    """`count` mutated inputs that still make a valid splat (every splat format at 300 Gaussians, and every mesh
    format converted to 400) through `pixie annotate`, `render`, `simulate` (3 frames) and `render` of the frames:
    successes, one-line refusals (exit 1: e.g. a flat splat that prepare reads as ground alone), exit-3 results (a
    NaN or a diverged run: allowed by the promises, but each is a valid input the pipeline could not handle) and
    broken promises (crashes count)."""
    folder = work / "pipeline"
    folder.mkdir()
    rng = np.random.default_rng([seed, 200])
    splats = {suffix: fc.valid_splat_bytes(suffix) for suffix in fc.SPLAT_SUFFIXES}
    meshes = {suffix: fc.valid_mesh_bytes(suffix) for suffix in fc.MESH_SUFFIXES_FUZZED}
    tally = collections.Counter()
    outcomes = collections.Counter()
    t0 = time.perf_counter()
    while outcomes["inputs"] < count:
        found = _valid_mutated_source(rng, splats, meshes, folder)
        if found is None:
            continue
        blob, suffix = found
        outcomes["inputs"] += 1
        problems = []
        for step, outcome in fc.through_the_pipeline_once(blob, suffix, folder).items():
            outcomes[f"{step} ok" if outcome.code == 0 else f"{step} exit {outcome.code}"] += 1
            problems += outcome.problems
        tally.update(categorise(problems))
        if problems and verbose:
            print(f"  pipeline on a mutated .{suffix}: {problems}", flush=True)
    print(f"\nmutated splats and meshes that still make a valid splat, through annotate, render, a 3-frame simulate "
          f"and render: {count} in {time.perf_counter() - t0:.0f} s; "
          + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())))
    print("  " + ", ".join(f"{c} {tally[c]}" for c in CATEGORIES))
    return {**dict(outcomes), **{c: tally[c] for c in CATEGORIES}}


# ------------------------------------------------------------------------- interruptions
def _simulate_argv(ply: Path, out: Path, scene: Path, frames: int) -> list[str]:
    return [sys.executable, "-m", "pixie_gs", "simulate", str(ply), "--out", str(out), "--scene", str(scene),
            "--frames", str(frames), "--device", "cpu", "--force", "-q"]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())} if folder.is_dir() else {}


def _is_whole_new(folder: Path, frames: int, n: int) -> bool:
    """Every frame of the new run present and consistent with tracks.npz (positions equal)."""
    from pixie_gs.splat import read_splat

    names = sorted(p.name for p in folder.iterdir())
    if names != [f"frame_{i:05d}.ply" for i in range(frames)] + ["preview.png", "tracks.npz"]:
        return False
    with np.load(folder / "tracks.npz") as tr:
        x = tr["x"]
    if x.shape != (frames, n, 3):
        return False
    return all(np.array_equal(read_splat(folder / f"frame_{i:05d}.ply").means, x[i]) for i in range(frames))


def run_interruptions(work: Path, trials: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    base = work / "interrupt"
    base.mkdir()
    n = 300
    ply = fc.write_ply(base / "in.ply", fc.vertex_table(n, materials=True))
    scene = base / "scene.json"
    scene.write_text(json.dumps(fc.scene_dict()))
    out = base / "out"
    old_frames, new_frames = 3, 16
    subprocess.run(_simulate_argv(ply, out, scene, old_frames), check=True, cwd=base)
    pristine = base / "pristine"
    shutil.copytree(out, pristine)
    old = _snapshot(out)
    t0 = time.perf_counter()
    subprocess.run(_simulate_argv(ply, out, scene, new_frames), check=True, cwd=base)
    run_s = time.perf_counter() - t0
    assert _is_whole_new(out, new_frames, n)
    results = {}
    print(f"\ninterrupting `pixie simulate --force` ({n} Gaussians, {new_frames} frames over an existing "
          f"{old_frames}-frame output; an uninterrupted run takes {run_s:.1f} s): {trials} trials per signal")
    print(f"{'signal':8s} {'old whole':>10s} {'new whole':>10s} {'mixed':>6s} {'leftovers':>10s} "
          f"{'tracebacks':>11s} {'input changed':>14s} {'signal lost':>12s}")
    before_input = ply.read_bytes()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        tally = collections.Counter()
        for _ in range(trials):
            shutil.rmtree(out)
            shutil.copytree(pristine, out)
            delay = float(rng.uniform(0.0, run_s * 1.05))
            proc = subprocess.Popen(_simulate_argv(ply, out, scene, new_frames), cwd=base,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    preexec_fn=fc.default_sigint)
            folder = out.stat().st_ino  # the commit swaps a new folder in under this name
            time.sleep(delay)
            still_working = proc.poll() is None and out.stat().st_ino == folder
            proc.send_signal(sig)
            _, err = proc.communicate(timeout=120)
            if still_working and proc.returncode == 0:
                tally["signal lost"] += 1  # sent before the commit, yet the run finished and exited 0
            if _snapshot(out) == old:
                tally["old whole"] += 1
            elif _is_whole_new(out, new_frames, n):
                tally["new whole"] += 1
            else:
                tally["mixed"] += 1
            if "Traceback" in err and "/pixie_gs/" not in err and any(
                    mark in err for mark in ("init_import_site", "<frozen site>", "<frozen runpy>")):
                tally["python start-up"] += 1  # Ctrl-C inside CPython's own start-up (site, or runpy finding
                # the module), before any pixie code runs
            elif "Traceback" in err:
                tally["tracebacks"] += 1
            stray = [p.name for p in base.iterdir() if p.name not in ("in.ply", "scene.json", "out", "pristine")]
            stray += [p.name for p in out.iterdir() if p.name.startswith(".")]
            if stray:
                if sig == signal.SIGKILL:
                    tally["killed-run staging folders"] += 1  # unavoidable; cleared by the next run
                else:
                    tally["leftovers"] += 1
            if ply.read_bytes() != before_input:
                tally["input changed"] += 1
        if sig == signal.SIGKILL:  # the next run must clear what SIGKILLed runs left
            shutil.rmtree(out)
            shutil.copytree(pristine, out)
            subprocess.run(_simulate_argv(ply, out, scene, old_frames), check=True, cwd=base)
            stray = [p.name for p in base.iterdir() if p.name not in ("in.ply", "scene.json", "out", "pristine")]
            tally["leftovers"] += len(stray)
        name = signal.Signals(sig).name
        results[name] = dict(tally)
        print(f"{name:8s} {tally['old whole']:10d} {tally['new whole']:10d} {tally['mixed']:6d} "
              f"{tally['leftovers']:10d} {tally['tracebacks']:11d} {tally['input changed']:14d} "
              f"{tally['signal lost']:12d}"
              + (f"   (staging folders left by killed runs: {tally['killed-run staging folders']}, all cleared "
                 f"by the next run)" if sig == signal.SIGKILL else "")
              + (f"   ({tally['python start-up']} landed in CPython's start-up, before any pixie code: its own "
                 "traceback)" if tally["python start-up"] else ""))
    return {"run_s": run_s, **results}


def _peak_anon_mb(argv: list[str], cwd: Path) -> tuple[float, float]:
    """(peak RssAnon MB, seconds) of a subprocess, sampled every 20 ms from /proc (Linux)."""
    proc = subprocess.Popen(argv, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    peak, t0 = 0, time.perf_counter()
    while proc.poll() is None:
        try:
            for line in Path(f"/proc/{proc.pid}/status").read_text().splitlines():
                if line.startswith("RssAnon:"):
                    peak = max(peak, int(line.split()[1]))
        except (OSError, ValueError):
            pass
        time.sleep(0.02)
    if proc.returncode != 0:
        raise RuntimeError(f"{argv} failed ({proc.returncode})")
    return peak / 1024, time.perf_counter() - t0


def run_memory(work: Path, n: int = 4000, frames: tuple[int, int] = (40, 400)) -> dict:
    """Peak anonymous memory of `simulate` for few vs many frames: flat when frames stream to disk
    (the (T,N,3) trajectory is a memory-mapped file; an in-memory one would add T·N·12 bytes)."""
    base = work / "memory"
    base.mkdir()
    ply = fc.write_ply(base / "in.ply", fc.vertex_table(n, materials=True))
    scene = base / "scene.json"
    scene.write_text(json.dumps(fc.scene_dict()))
    print(f"\nmemory of `pixie simulate` ({n} Gaussians, --no-prepare) for {frames[0]} vs {frames[1]} frames:")
    out = {}
    for f in frames:
        argv = _simulate_argv(ply, base / f"out{f}", scene, f) + ["--no-prepare"]
        peak, secs = _peak_anon_mb(argv, base)
        in_memory = f * n * 12 / 1e6
        out[f] = {"peak_anon_mb": round(peak, 1), "seconds": round(secs, 1), "trajectory_mb": round(in_memory, 1)}
        print(f"  {f:5d} frames: peak anonymous memory {peak:7.1f} MB in {secs:5.1f} s "
              f"(the trajectory would be {in_memory:.1f} MB if held in memory)")
        shutil.rmtree(base / f"out{f}")
    print(f"  growth {out[frames[1]]['peak_anon_mb'] - out[frames[0]]['peak_anon_mb']:+.1f} MB for "
          f"{frames[1] - frames[0]} more frames")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mutations", type=int, default=1000)
    ap.add_argument("--trials", type=int, default=20, help="interruptions per signal")
    ap.add_argument("--pipeline", type=int, default=100, help="valid mutated splats through annotate and simulate")
    ap.add_argument("--skip", default="", help="comma list of parts to skip: corpus,mutations,meshes,pipeline,interrupt,memory")
    ap.add_argument("--seed", type=int, default=None,
                    help="seed of the mutations and of the interruption moments (default: the recorded 2026 and 7)")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--json", default=None, help="also write the figures here")
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    work = Path(tempfile.mkdtemp(prefix="pixie_fuzz_"))
    figures = {}
    try:
        if "corpus" not in skip:
            figures["corpus"] = run_corpus(work, args.verbose)
        if "mutations" not in skip:
            figures["mutations"] = run_mutations(work, args.mutations, args.verbose,
                                                2026 if args.seed is None else args.seed)
        if "meshes" not in skip:
            figures["meshes"] = run_mesh_mutations(work, args.mutations, args.verbose,
                                                   2026 if args.seed is None else args.seed)
        if "pipeline" not in skip:
            figures["pipeline"] = run_pipeline(work, args.pipeline, args.verbose, 2026 if args.seed is None else args.seed)
        if "interrupt" not in skip:
            figures["interrupt"] = run_interruptions(work, args.trials, 7 if args.seed is None else args.seed)
        if "memory" not in skip:
            figures["memory"] = run_memory(work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
