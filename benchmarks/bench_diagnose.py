"""Benchmark of `pixie diagnose`: confusion matrix and gap reductions over hidden effects, and the
runtime of one 20k-particle, 2-second diagnosis.

    python benchmarks/bench_diagnose.py                      # both parts, CPU
    python benchmarks/bench_diagnose.py --part confusion     # only the confusion matrix
    python benchmarks/bench_diagnose.py --part runtime --device cuda   # runtime on a GPU

Confusion part: for each object (a generated two-part block, and a generated three-part shrub
from the dataset generator), each effect of the library hidden at two strengths (and once with
nothing hidden), measured data = the model simulated WITH the effect, 5 % of the Gaussians
tracked, 1 mm tracking noise; the diagnosis starts from the plain model. Prints the confusion
matrix (hidden → named first) and each case's RMS gap before/after.
Runtime part: one diagnosis of a 20 000-Gaussian object over 2 s (61 frames at 30 fps), with
the same outputs as the CLI (improved model written, re-simulated, PNG + rerun), reported
against the baseline of ONE full simulation of the same model measured in the same run.
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
from pixie_gs.diagnose.report import write_report  # noqa: E402
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


def runtime(device: str, n: int, seconds: float, fps: float, effect: str, values: dict) -> None:
    from pixie_gs.sim.run import simulate

    cloud = two_part_block(n, seed=0)
    scene = toss_scene(grid=32)
    frames = int(round(seconds * fps)) + 1
    start, cpu_start = time.perf_counter(), time.process_time()
    simulate(cloud, scene, frames, fps, device=device)
    one_sim = time.perf_counter() - start
    one_sim_cpu = time.process_time() - cpu_start
    arrays = make_measurement(cloud, scene, frames, fps, effect, None, values, fraction=FRACTION,
                              noise_m=NOISE_M, seed=7, device=device)
    start = time.perf_counter()
    cpu_start = time.process_time()
    tracks = tracks_from_arrays(arrays["t"], arrays["x"], cloud, ids=arrays["ids"])
    d = diagnose(cloud, scene, tracks, device=device, options=DiagnoseOptions(solver_floor=False))
    has_rerun = importlib.util.find_spec("rerun") is not None  # GPU boxes may lack rerun-sdk
    with tempfile.TemporaryDirectory() as out:
        summary = write_report(Path(out), d, cloud, device=device, rrd=has_rerun)
    total = time.perf_counter() - start
    cpu = time.process_time() - cpu_start
    named = d.effect
    print(f"runtime: {n} Gaussians, {seconds:g} s at {fps:g} fps, device {device}, hidden {effect} {values}")
    print(f"  one full simulation (baseline): {one_sim:.1f} s wall ({one_sim_cpu:.1f} s CPU)")
    print(f"  diagnosis incl. outputs: {total:.1f} s wall ({cpu:.1f} s CPU of this process) = "
          f"{total / one_sim:.1f} × one simulation (wall); "
          f"{d.runs} simulations ({d.sim_seconds:.1f} s in the simulator), reduced fitting model: "
          f"{'yes' if d.rounds and len(cloud) > DiagnoseOptions().fidelity.max_particles else 'no'}")
    print(f"  named: {label(named.effect, named.part) if named else 'nothing'} "
          f"{ {k: round(v, 3) for k, v in named.params.items()} if named else ''}; gap "
          f"{summary['gap_before']:.4f} → {summary['gap_after']:.4f} "
          f"({100 * summary['gap_reduction']:.1f}% smaller)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("all", "confusion", "runtime"), default="all")
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda")
    ap.add_argument("--particles", type=int, default=20000, help="Gaussians of the runtime object")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds of the runtime case")
    ap.add_argument("--block", type=int, default=500, help="Gaussians of the confusion block")
    ap.add_argument("--shrub", type=int, default=800, help="Gaussians of the confusion shrub")
    args = ap.parse_args()
    set_quiet(True)
    if args.part in ("all", "confusion"):
        confusion(args.device, frames=17, fps=25.0, n_block=args.block, n_shrub=args.shrub)
    if args.part in ("all", "runtime"):
        runtime(args.device, args.particles, args.seconds, 30.0, "air_drag", {"k_per_m": 1.5})


if __name__ == "__main__":
    main()
