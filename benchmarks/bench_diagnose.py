"""Benchmark of `pixie diagnose`: confusion matrix and gap reductions over hidden effects, and the
runtime of one 20k-particle, 2-second diagnosis.

    python benchmarks/bench_diagnose.py                      # both parts, CPU
    python benchmarks/bench_diagnose.py --part confusion     # only the confusion matrix
    python benchmarks/bench_diagnose.py --part runtime --device cuda   # runtime on a GPU
    python benchmarks/bench_diagnose.py --part runtime --batch off     # candidate runs one by one
    python benchmarks/bench_diagnose.py --part batch --device cuda     # K runs batched vs one by one
    python benchmarks/bench_diagnose.py --part runtime --device cuda --graph off   # no CUDA graphs
    python benchmarks/bench_diagnose.py --part runtime --device cuda --profile 40  # where the time goes

Confusion part: for each object (a generated two-part block, and a generated three-part shrub
from the dataset generator), each effect of the library hidden at two strengths (and once with
nothing hidden), measured data = the model simulated WITH the effect, 5 % of the Gaussians
tracked, 1 mm tracking noise; the diagnosis starts from the plain model. Prints the confusion
matrix (hidden → named first) and each case's RMS gap before/after.
Runtime part: one diagnosis of a 20 000-Gaussian object over 2 s (61 frames at 30 fps), with
the same outputs as the CLI (improved model written, re-simulated, PNG + rerun), reported
against the baseline of ONE full simulation of the same model measured in the same run.
Batch part: K variants (air drag 0…3 1/m) of the runtime object's reduced fitting model (3000
Gaussians, grid 24, 61 frames) simulated one after the other and as one batched simulation
(sim/batch.py), K = 1, 8, 32; prints both wall times and the speed-up, and checks the tracks agree.
`--batch auto|on|off`: candidate runs as one batched simulation per fitting stage (sim/batch.py;
auto = on a GPU only). Warp compiles its kernels once per machine: a warm-up before the timed
part runs both the unbatched and the batched kernels once, and its time is printed apart.
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pixie_gs.diagnose.measured import tracks_from_arrays  # noqa: E402
from pixie_gs.diagnose.pipeline import DiagnoseOptions, diagnose  # noqa: E402
from pixie_gs.diagnose.report import prefetch_plotting, write_report  # noqa: E402
from pixie_gs.diagnose.synthetic import HIDDEN_EFFECTS, make_measurement, toss_scene, two_part_block  # noqa: E402
from pixie_gs.progress import set_quiet  # noqa: E402

NOISE_M = 1e-3
FRACTION = 0.05


def shrub(n: int, seed: int = 0):
    """A generated shrub (stems, twigs, foliage: three elastic parts), placed with its base at z=0."""
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table

    cloud, _ = build_object(load_class_table()["shrubs"], object_seed(seed, "test", 0), n)
    return cloud


def objects(n_block: int, n_shrub: int) -> dict:
    return {"block": (two_part_block(n_block, seed=0), toss_scene()),
            "shrub": (shrub(n_shrub), toss_scene(size_m=0.35))}


def label(effect: str | None, part: int | None) -> str:
    if effect is None:
        return "nothing"
    return effect if part is None else f"{effect}[{part}]"


def confusion(device: str, frames: int, fps: float, n_block: int, n_shrub: int) -> None:
    rows = []
    for obj_name, (cloud, scene) in objects(n_block, n_shrub).items():
        cache: dict = {}
        part_ids = np.unique(cloud.get("part_id"))
        cases = [(None, None, {}, "-")]
        for effect, part, weak, strong in HIDDEN_EFFECTS:
            p = None if part is None else int(part_ids[min(part, len(part_ids) - 1)])
            if obj_name == "shrub" and part is not None:
                p = int(part_ids[-1]) if effect in ("part_stiffness", "part_density") else int(part_ids[0])
            p_strong = p
            if effect == "anchored_part":  # no strength to vary: anchor another part instead
                p_strong = int(part_ids[-1]) if p != int(part_ids[-1]) else int(part_ids[0])
            if effect == "plastic_yield":  # the catalogue's yield stresses are for E = 2 kPa: keep the strain
                E_part = float(np.median(cloud.get("E")[cloud.get("part_id") == p]))
                weak = {"yield_stress_pa": weak["yield_stress_pa"] / 2e3 * E_part}
                strong = {"yield_stress_pa": strong["yield_stress_pa"] / 2e3 * E_part}
            cases += [(effect, p, weak, "weak"), (effect, p_strong, strong, "strong")]
        for effect, part, values, strength in cases:
            start = time.perf_counter()
            arrays = make_measurement(cloud, scene, frames, fps, effect, part, values, fraction=FRACTION,
                                      noise_m=NOISE_M, seed=7, device=device)
            tracks = tracks_from_arrays(arrays["t"], arrays["x"], cloud, ids=arrays["ids"])
            # same-simulator data have no solver error by construction: the floor is off here
            d = diagnose(cloud, scene, tracks, device=device, cache=cache,
                         options=DiagnoseOptions(solver_floor=False))
            named = d.effect
            rows.append({
                "object": obj_name, "hidden": label(effect, part), "strength": strength,
                "named": label(named.effect, named.part) if named else "nothing",
                "correct": (named is None and effect is None) or
                           (named is not None and named.effect == effect and (part is None or named.part == part)),
                "gap_before": d.gap_before, "gap_after": d.gap_after, "runs": d.runs,
                "seconds": time.perf_counter() - start,
            })
            r = rows[-1]
            print(f"{obj_name:6s} {r['hidden']:22s} {strength:6s} → {r['named']:22s} "
                  f"{'ok ' if r['correct'] else 'MISS'} gap {r['gap_before']:.4f} → {r['gap_after']:.4f} "
                  f"({100 * (1 - r['gap_after'] / max(r['gap_before'], 1e-12)):5.1f}% smaller) "
                  f"{r['runs']:3d} sims {r['seconds']:5.1f} s", flush=True)
    print("\nconfusion matrix (rows: hidden effect; columns: named first; counts over objects × strengths)")
    names = ["nothing"] + [h[0] for h in HIDDEN_EFFECTS]
    counts: dict = defaultdict(int)
    for r in rows:
        hidden = r["hidden"].split("[")[0]
        named = r["named"].split("[")[0]
        counts[(hidden, named)] += 1
    short = {n: n[:8] for n in names}
    corner = "hidden / named"
    print(f"{corner:18s}" + "".join(f"{short[n]:>9s}" for n in names))
    for h in names:
        print(f"{h:18s}" + "".join(f"{counts[(h, n)]:9d}" for n in names))
    effect_rows = [r for r in rows if r["hidden"] != "nothing"]
    reductions = [1 - r["gap_after"] / r["gap_before"] for r in effect_rows]
    correct = sum(r["correct"] for r in rows)
    print(f"\nnamed correctly (effect and part): {correct}/{len(rows)}; "
          f"gap reduction over hidden-effect cases: median {100 * np.median(reductions):.1f}%, "
          f"min {100 * np.min(reductions):.1f}%, ≥80% in {sum(x >= 0.8 for x in reductions)}/{len(reductions)}; "
          f"mean {np.mean([r['seconds'] for r in rows]):.1f} s and {np.mean([r['runs'] for r in rows]):.0f} "
          "simulations per diagnosis (simulation cache shared per object)")


def output_imports(has_rerun: bool) -> float:
    """Import what the outputs need (matplotlib for the PNG, rerun for the recording) → seconds.
    Like Warp's start-up they are paid once per process (`pixie diagnose` starts them in the
    background before its diagnosis: report.prefetch_plotting); the fit itself imports nothing
    heavy (no scipy: lsq.py, kmeans.py)."""
    import importlib

    from pixie_gs.diagnose.report import PLOT_MODULES

    start = time.perf_counter()
    for name in PLOT_MODULES + (("rerun",) if has_rerun else ()):
        importlib.import_module(name)
    return time.perf_counter() - start


def runtime(device: str, n: int, seconds: float, fps: float, effect: str, values: dict,
            batch: bool | None = None, profile: int = 0, imports_timed: bool = False, repeat: int = 1) -> None:
    from pixie_gs.sim.batch import simulate_batch
    from pixie_gs.sim.run import simulate

    cloud = two_part_block(n, seed=0)
    scene = toss_scene(grid=32)
    frames = int(round(seconds * fps)) + 1
    start = time.perf_counter()
    small = two_part_block(200, seed=1)
    simulate(small, scene, 3, fps, device=device)  # warm-up: Warp init and kernel (compile or) load
    simulate_batch([(small, scene), (small, scene)], 3, fps, device=device)
    warm = time.perf_counter() - start
    has_rerun = importlib.util.find_spec("rerun") is not None  # GPU boxes may lack rerun-sdk
    imports = None if imports_timed else output_imports(has_rerun)
    start = time.perf_counter()
    simulate(cloud, scene, frames, fps, device=device)
    one_sim = time.perf_counter() - start
    arrays = make_measurement(cloud, scene, frames, fps, effect, None, values, fraction=FRACTION,
                              noise_m=NOISE_M, seed=7, device=device)
    for i in range(repeat):
        if repeat > 1:
            print(f"-- repeat {i + 1} of {repeat}")
        diagnose_once(device, cloud, scene, arrays, one_sim, batch, profile, imports, warm, has_rerun,
                      f"{n} Gaussians, {seconds:g} s at {fps:g} fps, device {device}, hidden {effect} {values}")


def diagnose_once(device: str, cloud, scene, arrays: dict, one_sim: float, batch: bool | None, profile: int,
                  imports: float | None, warm: float, has_rerun: bool, what: str) -> None:
    """One timed diagnosis (+ outputs) of the runtime case, and its figures and timeline."""
    profiler = None
    if profile:
        import cProfile

        profiler = cProfile.Profile()
        profiler.enable()
    start = time.perf_counter()
    cpu_start = time.process_time()
    tracks = tracks_from_arrays(arrays["t"], arrays["x"], cloud, ids=arrays["ids"])
    prefetch_plotting()  # as `pixie diagnose` does before a diagnosis
    d = diagnose(cloud, scene, tracks, device=device, options=DiagnoseOptions(solver_floor=False, batch=batch))
    fitted = time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        summary = write_report(Path(out), d, cloud, device=device, rrd=has_rerun)
    total = time.perf_counter() - start
    cpu = time.process_time() - cpu_start
    if profiler is not None:
        import pstats

        profiler.disable()
        stats = pstats.Stats(profiler, stream=sys.stdout)
        stats.sort_stats("cumulative").print_stats(profile)
        stats.sort_stats("tottime").print_stats(profile)
    named = d.effect
    print(f"runtime: {what}, "
          f"batch {'auto' if batch is None else ('on' if batch else 'off')}"
          f"{graphs(device)}")
    print(f"  warm-up (Warp init, kernels loaded or compiled; not timed below): {warm:.1f} s")
    if imports is not None:
        print(f"  imports for the outputs (matplotlib{', rerun' if has_rerun else ''}; not timed below, "
              f"--imports timed keeps them in): {imports:.2f} s")
    print(f"  one full simulation (baseline): {one_sim:.1f} s wall")
    print(f"  diagnosis incl. outputs: {total:.1f} s wall ({cpu:.1f} s CPU of this process) = "
          f"{total / one_sim:.1f} × one simulation (wall); "
          f"{d.runs} model runs ({d.sim_batches} batched simulations of several runs each), "
          f"{d.sim_seconds:.1f} s in the simulator; fitting {fitted - start:.1f} s, outputs "
          f"{total - (fitted - start):.1f} s; reduced fitting model: "
          f"{'yes' if d.rounds and len(cloud) > DiagnoseOptions().fidelity.max_particles else 'no'}; "
          f"load average {open('/proc/loadavg').read().split()[0] if Path('/proc/loadavg').exists() else '?'}")
    print(f"  named: {label(named.effect, named.part) if named else 'nothing'} "
          f"{ {k: round(v, 3) for k, v in named.params.items()} if named else ''}; gap "
          f"{summary['gap_before']:.4f} → {summary['gap_after']:.4f} "
          f"({100 * summary['gap_reduction']:.1f}% smaller)")
    timeline(d.sim_log, start, fitted)
    if d.rounds and d.rounds[0].ranking:
        top = d.rounds[0].ranking[:4]
        print("  round-1 ranking: " + "; ".join(
            f"{s.label} {({k: round(v, 3) for k, v in s.params.items()})} ΔBIC {s.delta_bic:.0f}" for s in top)
              + (f"; ambiguous with: {', '.join(a.label for a in d.ambiguous)}" if d.ambiguous else ""))


def graphs(device: str) -> str:
    batch_module = sys.modules["pixie_gs.sim.batch"]
    loop = ", frames on the device" if batch_module.DEVICE_LOOP else ""
    if device == "cpu" or not batch_module.CUDA_GRAPH:
        return loop
    return f", CUDA graphs of 1 and {batch_module.GRAPH_SUBSTEPS} substeps{loop}"


def timeline(log: list, start: float, fitted: float) -> None:
    """Every simulation of the diagnosis in order (stage, when, how long, how big), the host time
    between simulations, and the totals per stage."""
    print("  simulations (stage, start s, seconds, runs, particles, grid, frames; host s since the previous one; "
          "batched: set-up s, frame loop s, of it waiting in syncs s, substeps):")
    last = start
    per_stage: dict = defaultdict(lambda: [0, 0, 0.0, 0.0])
    for rec in log:
        gap = rec.start_s - last
        st = rec.stats
        split = (f"   set-up {st['setup_s']:.3f} loop {st['loop_s']:.3f} wait {st['wait_s']:.3f} "
                 f"substeps {st['substeps']}") if st else ""
        print(f"    {rec.stage:10s} {rec.start_s - start:6.2f} {rec.seconds:6.3f} {rec.runs:3d} {rec.particles:7d} "
              f"{rec.grid:3d} {rec.frames:3d}   host {gap:6.3f}{split}")
        last = rec.start_s + rec.seconds
        acc = per_stage[rec.stage.split()[0]]
        acc[0] += 1
        acc[1] += rec.runs
        acc[2] += rec.seconds
        acc[3] += gap
    print(f"    host after the last simulation until the fit returned: {fitted - last:.3f} s")
    print("  per stage: " + "; ".join(f"{k} {v[0]} sims / {v[1]} runs {v[2]:.2f} s (+{v[3]:.2f} s host before)"
                                      for k, v in per_stage.items()))


def batch_speed(device: str, n: int, seconds: float, fps: float, sizes: tuple[int, ...] = (1, 8, 32)) -> None:
    import copy

    from pixie_gs.diagnose.forward import Fidelity, reduced_subset
    from pixie_gs.sim.batch import simulate_batch
    from pixie_gs.sim.run import simulate

    fid = Fidelity()
    cloud = two_part_block(n, seed=0)
    keep, _ = reduced_subset(n, np.arange(0, n, 20), fid)
    sub = cloud.subset(keep)
    scene = toss_scene(grid=24)
    frames = int(round(seconds * fps)) + 1
    simulate(sub, scene, 3, fps, device=device, quiet=True)  # warm-up (kernel load / compile)
    simulate_batch([(sub, scene)] * 2, 3, fps, device=device)
    print(f"batch: {len(sub)} Gaussians per run, grid {scene.domain.grid}, {frames} frames, device {device}")
    for k in sizes:
        models = []
        for i in range(k):
            sc = copy.deepcopy(scene)
            sc.air_drag = 3.0 * i / max(k - 1, 1)
            models.append((sub, sc))
        start = time.perf_counter()
        alone = [simulate(c, sc, frames, fps, device=device, quiet=True) for c, sc in models]
        t_alone = time.perf_counter() - start
        start = time.perf_counter()
        batched = simulate_batch(models, frames, fps, device=device)
        t_batch = time.perf_counter() - start
        diff = max(float(np.abs(a.x - b.x).max()) for a, b in zip(alone, batched))
        print(f"  K={k:3d}: one by one {t_alone:6.2f} s ({t_alone / k:.3f} s per run), batched {t_batch:6.2f} s "
              f"({t_batch / k:.3f} s per run) → {t_alone / t_batch:5.1f}× faster; max track difference {diff:.2g} m")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("all", "confusion", "runtime", "batch"), default="all")
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda")
    ap.add_argument("--particles", type=int, default=20000, help="Gaussians of the runtime object")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds of the runtime case")
    ap.add_argument("--block", type=int, default=500, help="Gaussians of the confusion block")
    ap.add_argument("--shrub", type=int, default=800, help="Gaussians of the confusion shrub")
    ap.add_argument("--batch", choices=("auto", "on", "off"), default="auto",
                    help="candidate runs as batched simulations (auto: on a GPU only)")
    ap.add_argument("--graph", choices=("on", "off"), default=None,
                    help="GPU: batched substeps replayed as one CUDA graph each (default on: sim/batch.py CUDA_GRAPH)")
    ap.add_argument("--imports", choices=("warm", "timed"), default="warm",
                    help="runtime part: import the outputs' modules (matplotlib, rerun) during the warm-up "
                         "(default, printed apart) or inside the timed part")
    ap.add_argument("--repeat", type=int, default=1, help="runtime part: timed diagnoses in this process")
    ap.add_argument("--device-loop", choices=("on", "off"), default=None,
                    help="batched frames planned, stepped and guarded on the device with one read-back at the "
                         "end (sim/device_frames.py; default sim/batch.py DEVICE_LOOP)")
    ap.add_argument("--graph-substeps", type=int, default=None, metavar="N",
                    help="GPU: substeps per replayed CUDA graph besides the single-substep one "
                         "(default sim/batch.py GRAPH_SUBSTEPS; 1: single-substep graphs only)")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="runtime part: profile the diagnosis (cProfile) and print the top N functions")
    args = ap.parse_args()
    set_quiet(True)
    if args.graph is not None:
        import pixie_gs.sim.batch as batch_module

        batch_module.CUDA_GRAPH = args.graph == "on"
    if args.device_loop is not None:
        import pixie_gs.sim.batch as batch_module

        batch_module.DEVICE_LOOP = args.device_loop == "on"
    if args.graph_substeps is not None:
        import pixie_gs.sim.batch as batch_module

        batch_module.GRAPH_SUBSTEPS = max(1, args.graph_substeps)
    if args.part in ("all", "confusion"):
        confusion(args.device, frames=17, fps=25.0, n_block=args.block, n_shrub=args.shrub)
    if args.part in ("all", "runtime"):
        runtime(args.device, args.particles, args.seconds, 30.0, "air_drag", {"k_per_m": 1.5},
                batch={"auto": None, "on": True, "off": False}[args.batch], profile=args.profile,
                imports_timed=args.imports == "timed", repeat=args.repeat)
    if args.part == "batch":
        batch_speed(args.device, args.particles, args.seconds, 30.0)


if __name__ == "__main__":
    main()
