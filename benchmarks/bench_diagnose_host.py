"""Host-side (CPU) costs of `pixie diagnose` outside the simulator, on the runtime case's geometry
(20 000 Gaussians, 1000 tracked points, 61 frames), each next to the baseline it replaced,
measured in the same run:

    python benchmarks/bench_diagnose_host.py

  * outlier_tracks' neighbour distances: vectorised (checks.outlier_distances) vs the per-track
    loop (checks.outlier_distances_reference);
  * the Gaussian spacing (nearest neighbour of each of 20k centres): numpy cell grid (knn.py) vs
    scipy's cKDTree, the latter with the import of scipy.spatial it needs (fresh interpreter);
  * the imports the fit and the PNG need (scipy.optimize + scipy.cluster.vq before, pixie_gs.lsq +
    pixie_gs.kmeans now; matplotlib.figure vs matplotlib.pyplot), each in a fresh interpreter.
Prints wall and process-CPU seconds (fresh interpreters: less numpy's own import) and the load
average (a shared machine: compare CPU seconds).
"""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pixie_gs.diagnose.checks import gaussian_spacing, outlier_distances, outlier_distances_reference  # noqa: E402
from pixie_gs.diagnose.synthetic import two_part_block  # noqa: E402


def timed(fn, repeat: int = 3) -> tuple[float, float, object]:
    """(best wall s, best CPU s, result) over `repeat` calls."""
    walls, cpus = [], []
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return min(walls), min(cpus), out


def fresh(code: str) -> tuple[float, float]:
    """(wall s, CPU s) of `code` in a fresh interpreter (imports not yet loaded)."""
    prog = ("import time; w = time.perf_counter(); c = time.process_time()\n" + code +
            "\nprint(time.perf_counter() - w, time.process_time() - c)")
    out = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parent.parent)  # this checkout's pixie_gs
    wall, cpu = (float(v) for v in out.stdout.split()[-2:])
    return wall, cpu


def plan_per_frame(cloud, runs: int = 27, frames: int = 2000) -> None:
    """The host's per-frame substep plan of a screening batch (27 runs of the reduced model): one
    run at a time (BatchedSolver._substeps, the reference) vs all at once (_plan)."""
    import copy

    from pixie_gs.diagnose.synthetic import toss_scene
    from pixie_gs.sim.batch import BatchedSolver
    from pixie_gs.sim.run import build_particles

    scene = toss_scene(grid=24)
    sub = cloud.subset(np.arange(0, len(cloud), 7))
    models = []
    for i in range(runs):
        sc = copy.deepcopy(scene)
        sc.air_drag = 0.1 * i
        models.append((build_particles(sub, sc)[0], sc))
    solver = BatchedSolver(models, "cpu")
    solver.step_frame(1.0 / 30)  # the t = 0 impulse is spent
    maxima = np.stack([np.linspace(0.5, 3.0, runs), np.zeros(runs)], axis=1)
    rule = lambda: [solver._substeps(r, 1.0 / 30, float(maxima[r, 0]), float(maxima[r, 1])) for r in range(runs)]  # noqa: E731
    assert solver._plan(1.0 / 30, maxima).tolist() == rule()
    w_loop, _, _ = timed(lambda: [rule() for _ in range(frames)])
    w_plan, _, _ = timed(lambda: [solver._plan(1.0 / 30, maxima) for _ in range(frames)])
    print(f"  substep plan of {runs} runs per frame: per-run loop {1e6 * w_loop / frames:.0f} µs, "
          f"all at once {1e6 * w_plan / frames:.0f} µs (same counts)")


def main() -> None:
    cloud = two_part_block(20000, seed=0)
    means = cloud.means.astype(np.float64)
    rng = np.random.default_rng(7)
    T, M = 61, 1000
    ids = np.sort(rng.choice(len(means), M, replace=False))
    rest = means[ids]
    t = np.arange(T) / 30.0
    r = 0.01 * rest[None, :, :1] * t[:, None, None] + rng.normal(scale=1e-3, size=(T, M, 3))
    visible = rng.random((T, M)) > 0.05
    r = np.where(visible[:, :, None], r, np.nan)
    part = cloud.get("part_id")[ids]
    print(f"host-side diagnose stages: {len(means)} Gaussians, {M} tracks × {T} frames; "
          f"load average {open('/proc/loadavg').read().split()[0]}")

    w_fast, c_fast, d_fast = timed(lambda: outlier_distances(r, visible, rest, part))
    w_ref, c_ref, d_ref = timed(lambda: outlier_distances_reference(r, visible, rest, part), repeat=1)
    print(f"  outlier distances: vectorised {w_fast:.3f} s wall / {c_fast:.3f} s CPU, per-track loop "
          f"{w_ref:.3f} s / {c_ref:.3f} s CPU → {c_ref / max(c_fast, 1e-9):.1f}× less CPU; "
          f"max |difference| {np.abs(d_fast - d_ref).max():.2g}")

    plan_per_frame(cloud)

    w_np, c_np = fresh("import numpy")  # subtracted below: every fresh interpreter imports numpy first
    w_grid, c_grid, s_grid = timed(lambda: gaussian_spacing(means))
    np.save(Path("/tmp") / "pixie_bench_means.npy", means)
    w_kd, c_kd = fresh("import numpy as np\nfrom scipy.spatial import cKDTree\n"
                       "m = np.load('/tmp/pixie_bench_means.npy'); d, _ = cKDTree(m).query(m, k=2)")
    print(f"  Gaussian spacing: numpy cell grid {w_grid:.3f} s wall / {c_grid:.3f} s CPU (spacing {s_grid:.5f}); "
          f"cKDTree incl. importing scipy.spatial {w_kd - w_np:.3f} s / {c_kd - c_np:.3f} s CPU")

    for label, code in (("scipy.optimize + scipy.cluster.vq (the fit, before)", "import scipy.optimize, scipy.cluster.vq"),
                        ("pixie_gs.lsq + pixie_gs.kmeans (the fit, now)", "import pixie_gs.lsq, pixie_gs.kmeans"),
                        ("matplotlib.figure + backend_agg (PNG, now)",
                         "import matplotlib.figure, matplotlib.backends.backend_agg"),
                        ("matplotlib.pyplot, Agg (PNG, before)",
                         "import matplotlib\nmatplotlib.use('Agg')\nimport matplotlib.pyplot")):
        w, c = fresh("import numpy\n" + code)
        print(f"  import {label}: {w - w_np:.3f} s wall / {c - c_np:.3f} s CPU")
    print("  (the PNG's imports run in a background thread while the first simulations run: prefetch.py;"
          " the fit imports no scipy)")


if __name__ == "__main__":
    main()
