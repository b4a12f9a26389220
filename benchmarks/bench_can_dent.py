"""Soda can at TRUE stiffness struck by an impulse (pixie_gs/sim/can_scene.py): dent depth per
millisecond for a few blow speeds and grids, substeps per frame (the budget used) and wall time.
Meant for a GPU (at true stiffness aluminium needs ~4,000 substeps per ms at dx = 2 mm).

    python benchmarks/bench_can_dent.py --device cuda
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--dx-mm", default="2,1", help="grid spacings (mm); the wall is one cell thick")
    ap.add_argument("--speeds", default="100,200,400", help="blow speeds (m/s) given to the struck patch")
    ap.add_argument("--ms", type=int, default=10, help="simulated milliseconds (one frame each)")
    args = ap.parse_args()
    from pixie_gs.sim import MPMSolver
    from pixie_gs.sim.can_scene import diameter_along_blow, soda_can

    for dx_mm in (float(g) for g in args.dx_mm.split(",")):
        for dv in (float(v) for v in args.speeds.split(",")):
            p, scene, band = soda_can(dx_mm / 1000, dv, "true", 1_000_000)
            sim = MPMSolver(p, scene, args.device)
            d0 = diameter_along_blow(p.x, band)
            t0 = time.perf_counter()
            dents = []
            for _ in range(args.ms):
                sim.step_frame(1e-3)
                dents.append(d0 - diameter_along_blow(sim.positions(), band))
            wall = time.perf_counter() - t0
            dents = np.array(dents)
            print(f"dx {1000 * scene.dx:.1f} mm ({len(p):,} particles), blow {dv:g} m/s: "
                  f"{sim.substeps_last_frame:,} substeps/ms, {wall:.1f} s wall; dent per ms (mm) "
                  f"{np.round(1000 * dents, 2).tolist()}; final/diameter {dents[-1] / d0:.3f}, "
                  f"final/max {dents[-1] / max(dents.max(), 1e-12):.2f}", flush=True)


if __name__ == "__main__":
    main()
