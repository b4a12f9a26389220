"""Axisymmetric sand column collapse vs the experimental runout law (Lube et al. 2004,
Lajeunesse et al. 2004): (r∞ − r0)/r0 ≈ 1.24·a for a < 1.7 and ≈ 1.6·a^½ above, a = h0/r0.

A quarter column stands in the corner of the domain (the two slip walls are its symmetry
planes) on a rough floor and collapses under gravity with the sand model (Drucker–Prager,
scene default friction angle). r∞ is the radius holding 99.9 % of the grains once everything
has stopped. Prints one line per aspect ratio and writes a plot (default docs/sand_collapse.png).

    python benchmarks/bench_sand_collapse.py                       # a = 0.5, 1, 2, 3; 12 cells per r0
    python benchmarks/bench_sand_collapse.py --aspect 0.5 1 --cells-per-radius 8
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from pixie_gs.materials import SAND
from pixie_gs.sim import MPMSolver, Particles, Scene

R0_M = 0.05  # column radius (m)
DENSITY = 2000.0  # kg/m³
# Runout depends on friction, not stiffness, while the elastic strain ρ g h0 / E stays ≪ 1
# (≤ 1.5 % here); a softer E than real sand (4e7–6e7 Pa) keeps the CFL substep affordable on a CPU.
E_PA, NU = 2e5, 0.3


def runout_law(a: np.ndarray | float) -> np.ndarray:
    """Normalised runout (r∞ − r0)/r0 of the experiments."""
    a = np.asarray(a, dtype=np.float64)
    return np.where(a < 1.7, 1.24 * a, 1.6 * np.sqrt(a))


def collapse(aspect: float, cells_per_radius: int, ground_friction: float, device: str) -> dict:
    """Simulate one column until it stops; returns runout and the final particles."""
    dx = R0_M / cells_per_radius
    h0 = aspect * R0_M
    reach = R0_M * (1.0 + float(runout_law(aspect))) * 1.5 + 6 * dx
    scene = Scene.from_dict({
        "domain": {"size_m": [reach, reach, h0 + 8 * dx], "grid": int(round(reach / dx)),
                   "origin": [-3 * dx, -3 * dx, -3 * dx]},
        "ground": {"enabled": True, "height_m": 0.0, "friction": ground_friction},
        "walls": "slip",
    })
    column = Particles.lattice((0.0, 0.0, 0.0), (R0_M, R0_M, h0), dx / 2,
                               inside=lambda x: np.hypot(x[:, 0], x[:, 1]) < R0_M,
                               E=E_PA, nu=NU, density=DENSITY, material_id=SAND)
    sim = MPMSolver(column, scene, device=device)
    start = time.perf_counter()
    t_max = 4.0 * np.sqrt(h0 / 9.81) + 0.3
    while sim.time_s < t_max:
        sim.step_frame(0.02)
        if sim.time_s > 0.2 and np.abs(sim.velocities()).max() < 0.005:  # m/s: at rest
            break
    x = sim.positions()
    r = np.hypot(x[:, 0], x[:, 1])
    r_inf = float(np.percentile(r, 99.9))
    return {"a": aspect, "n": len(column), "runout": (r_inf - R0_M) / R0_M, "law": float(runout_law(aspect)),
            "t_stop_s": sim.time_s, "wall_s": time.perf_counter() - start, "r": r, "z": x[:, 2],
            "substeps": sim.particle_substeps // len(column)}


def plot(results: list[dict], path: Path, cells: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [1, 1.4]})
    a = np.linspace(0.3, 3.2, 200)
    law = runout_law(a)
    ax.fill_between(a, 0.8 * law, 1.2 * law, color="0.85", label="law ±20 %")
    ax.plot(a, law, "k-", label="Lube / Lajeunesse 2004")
    ax.plot([r["a"] for r in results], [r["runout"] for r in results], "o", color="tab:orange",
            label=f"pixie-gs MPM ({cells} cells per r0)")
    ax.set_xlabel("aspect ratio a = h0 / r0")
    ax.set_ylabel("normalised runout (r∞ − r0) / r0")
    ax.set_title("Sand column collapse: runout")
    ax.legend(loc="upper left", fontsize=8)
    for res in results:
        order = np.argsort(res["r"])
        r, z = res["r"][order] / R0_M, res["z"][order] / R0_M
        bins = np.linspace(0, r.max(), 60)
        idx = np.digitize(r, bins)
        top = [z[idx == i].max() if np.any(idx == i) else np.nan for i in range(1, len(bins))]
        line, = ax2.plot(bins[1:], top, label=f"a = {res['a']:g}")
        ax2.plot([0, 1, 1], [res["a"], res["a"], 0], ":", color=line.get_color(), lw=0.8)
    ax2.set_xlabel("r / r0")
    ax2.set_ylabel("deposit height / r0")
    ax2.set_title("final deposits (dotted: initial columns)")
    ax2.set_aspect("equal")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--aspect", type=float, nargs="+", default=[0.5, 1.0, 2.0, 3.0])
    ap.add_argument("--cells-per-radius", type=int, default=12)
    ap.add_argument("--ground-friction", type=float, default=0.5, help="floor Coulomb μ (rough base)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--plot", type=Path, default=Path("docs/sand_collapse.png"))
    args = ap.parse_args()
    results = []
    for aspect in args.aspect:
        res = collapse(aspect, args.cells_per_radius, args.ground_friction, args.device)
        err = res["runout"] / res["law"] - 1.0
        print(f"a={aspect:4.2f}  particles={res['n']:6d}  runout={res['runout']:.3f}  law={res['law']:.3f}  "
              f"error={100 * err:+5.1f}%  stopped at t={res['t_stop_s']:.2f} s  substeps={res['substeps']}  "
              f"wall={res['wall_s']:.0f} s", flush=True)
        results.append(res)
    within = sum(abs(r["runout"] / r["law"] - 1.0) <= 0.2 for r in results)
    print(f"within 20 % of the law: {within}/{len(results)}")
    plot(results, args.plot, args.cells_per_radius)
    print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
