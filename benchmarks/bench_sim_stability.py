"""Simulator stability over random material draws from the dataset's class ranges (DESIGN.md).

Each run builds a small object of one class (multi-part classes stack their parts as slabs,
bottom part first: e.g. tree = pot (stationary) / trunk / leaves), draws every part's
density, E and ν from the class ranges (single values widened: ρ ×[0.8, 1.25], E ×[0.5, 2]
log-uniform, ν ±0.03), gives it a random velocity, drops it on the ground and simulates.
A run succeeds when the solver's explosion guard never fires and every position is finite.
Prints one line per failure and the success rate (target 100 %).

    python benchmarks/bench_sim_stability.py                # 200 runs
    python benchmarks/bench_sim_stability.py --runs 20 --seed 1
"""
from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

from pixie_gs.errors import ComputationError
from pixie_gs.materials import JELLY, MATERIAL_NAMES, METAL, SAND, SNOW, STATIONARY
from pixie_gs.sim import MPMSolver, Particles, Scene

# class -> parts (bottom to top): (ρ kg/m³, E Pa, ν, material); a pair is a [lo, hi] range
CLASSES: dict[str, list[tuple[object, object, object, int]]] = {
    "tree": [(400, 2e8, 0.4, STATIONARY), (400, 2e6, 0.4, JELLY), (200, 2e4, 0.4, JELLY)],
    "flowers": [(500, 1e6, 0.3, STATIONARY), (100, 1e4, 0.4, JELLY)],
    "shrubs": [(300, 1e5, 0.35, JELLY), (250, 6e4, 0.38, JELLY), (150, 2e4, 0.40, JELLY)],
    "grass": [(1200, 5e5, 0.30, STATIONARY), (80, 1e4, 0.45, JELLY)],
    "rubber ducks & toys": [((80, 150), (3e4, 5e4), (0.4, 0.45), JELLY)],
    "sport balls": [((80, 150), (3e4, 5e4), (0.4, 0.45), JELLY)],
    "soda cans": [((2600, 2800), (5e10, 8e10), (0.25, 0.35), METAL)],
    "metal crates": [((2500, 2900), (8e7, 1.2e8), (0.25, 0.35), METAL)],
    "sand": [((1800, 2200), (4e7, 6e7), (0.25, 0.35), SAND)],
    "snow & mud": [((2000, 3000), (8e4, 1.2e5), (0.15, 0.25), SNOW)],
}


def draw(value: object, rng: np.random.Generator, kind: str) -> float:
    """Uniform in a [lo, hi] range; a single value is widened first (E log-uniformly)."""
    if isinstance(value, tuple):
        lo, hi = value
        return float(rng.uniform(lo, hi))
    v = float(value)  # type: ignore[arg-type]
    if kind == "E":
        return v * float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))
    if kind == "rho":
        return v * float(rng.uniform(0.8, 1.25))
    return float(np.clip(v + rng.uniform(-0.03, 0.03), 0.1, 0.48))


def build(class_name: str, scene: Scene, size_m: float, rng: np.random.Generator) -> Particles:
    parts = CLASSES[class_name]
    h = size_m / len(parts)
    pieces = []
    for k, (rho, E, nu, mat) in enumerate(parts):
        lo = (-size_m / 2, -size_m / 2, 0.05 + k * h)
        hi = (size_m / 2, size_m / 2, 0.05 + (k + 1) * h)
        pieces.append(Particles.lattice(lo, hi, scene.dx / 2, E=draw(E, rng, "E"), nu=draw(nu, rng, "nu"),
                                        density=draw(rho, rng, "rho"), material_id=mat, part_id=k))
    fields = ("x", "volume", "E", "nu", "density", "material_id", "part_id")
    merged = {f: np.concatenate([getattr(p, f) for p in pieces]) for f in fields}
    v = np.tile(rng.uniform(-1.0, 1.0, 3), (len(merged["x"]), 1))
    return Particles(v=v, **merged)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=8, help="frames of 1/30 s per run")
    ap.add_argument("--max-substeps", type=int, default=400, help="solver.max_substeps_per_frame")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    scene = Scene.from_dict({"domain": {"size_m": 0.5, "grid": 25}, "ground": {"friction": 0.5},
                             "solver": {"max_substeps_per_frame": args.max_substeps}})
    names = list(CLASSES)
    ok, failures, per_class = 0, [], Counter()
    start = time.perf_counter()
    substeps = 0
    for run in range(args.runs):
        name = names[int(rng.integers(len(names)))]
        per_class[name] += 1
        particles = build(name, scene, 0.12, rng)
        try:
            sim = MPMSolver(particles, scene, device=args.device)
            for _ in range(args.frames):
                sim.step_frame(1 / 30)
                substeps += sim.substeps_last_frame
            if not np.isfinite(sim.positions()).all():
                raise ComputationError("non-finite positions")
            ok += 1
        except ComputationError as exc:
            mats = sorted({MATERIAL_NAMES[int(m)] for m in particles.material_id})
            failures.append(f"run {run} ({name}: {', '.join(mats)}; E={np.unique(particles.E).tolist()}): {exc}")
            print("FAIL", failures[-1], flush=True)
        if (run + 1) % 20 == 0:
            print(f"  {run + 1} runs, {ok} ok, {time.perf_counter() - start:.0f} s", flush=True)
    print(f"classes drawn: {dict(per_class)}")
    print(f"success rate: {ok}/{args.runs} = {100.0 * ok / args.runs:.1f} %  "
          f"({args.frames} frames each, {substeps / args.runs:.0f} substeps per run on average, "
          f"{time.perf_counter() - start:.0f} s total)")


if __name__ == "__main__":
    main()
