"""Simulator throughput: particle-substeps per second for an elastic block, and memory per particle.

For each size (default 100k and 1M particles) an elastic jelly block (E = 1e5 Pa, ν = 0.3,
ρ = 1000 kg/m³, 8 particles per cell) rests on the ground under gravity; the Warp MPMSolver
runs `--warmup` substeps (kernel compilation, caches), then `--substeps` timed substeps as ONE
`step_frame` call (device synchronised before and after; the frame's CFL reduction, launches,
divergence guard and any re-sort are all inside the timed figure). Figures printed:

- particle order (`--order`, several allowed): `lattice` = the block as generated, solver sorting
  off (the best case); `random` = particles shuffled (what a splat file gives), solver sorting
  off; `sorted` = particles shuffled, the solver keeps them in grid-cell order (its default,
  re-sorted at the start of every frame);
- particle-substeps/s = particles × substeps / seconds;
- per-kernel split (P2G, grid update, G2P) per substep, from a second, instrumented frame (CUDA
  events after each kernel; on the CPU, where launches are synchronous, wall clock), and the
  host/device split of the timed frame: host seconds in the re-sort, the CFL reduction, issuing
  the launches, and the guard (which includes waiting for the device to finish the frame);
- memory per particle: bytes of the solver's Warp arrays whose length is the particle count
  (particle state), and all of its Warp arrays (grid included) divided by the particle count;
- with `--variant`s (sorted order): every variant against the baseline row, timed on the same
  frames in this run — the chunked P2G (`--variant chunked`, the GPU default before the column
  P2G) when it is among the variants, else the first variant; the row of the solver's default
  (`--variant auto`: on a GPU the column P2G carrying affine matrices in blocks of 128) is
  labelled "default", the chunked one "baseline", and on a GPU a "new default vs baseline" line
  gives their ratio;
- baseline ratio: the same substep written straightforwardly in numpy (quadratic B-spline
  MLS-MPM, fixed-corotated stress, scatter with np.bincount), timed in this same run on a small
  block (`--baseline-particles`), and Warp's throughput divided by it. The 100k → 1M scaling
  (throughput ratio) is printed too. Wall and process-CPU seconds are both printed: on a shared
  machine the wall figure drops when other jobs compete for the cores (Warp's CPU backend runs a
  kernel on one thread).

Usage:
    python benchmarks/bench_sim_throughput.py --device cpu --sizes 100000 1000000
    python benchmarks/bench_sim_throughput.py --device cuda          # the H100 figures
    python benchmarks/bench_sim_throughput.py --device cuda --sizes 1000000 4000000 --order sorted \
        --frames 3 --variant chunked --variant auto      # the default against the previous one
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

E_PA, NU, RHO = 1e5, 0.3, 1000.0
PARTICLES_PER_CELL = 8


def block_problem(n_target: int, ppc: int = PARTICLES_PER_CELL, shuffle: bool = False):
    """(Particles, Scene): a cube block of ≈ n_target particles on a lattice of `ppc` per cell,
    resting on the ground in the middle of a domain twice its size (`shuffle`: in random order)."""
    from pixie_gs.sim.particles import Particles
    from pixie_gs.sim.scene import Scene

    per_axis = max(1, round(ppc ** (1 / 3)))
    side_particles = max(2, round(n_target ** (1 / 3)))
    cells = max(2, math.ceil(side_particles / per_axis))
    block_m = 0.5
    dx = block_m / cells
    grid = 2 * cells + 8
    spacing = dx / per_axis
    ax = (np.arange(side_particles) + 0.5) * spacing
    x = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    side = side_particles * spacing
    x = x - np.array([side / 2, side / 2, 0.0])
    if shuffle:
        x = x[np.random.default_rng(0).permutation(len(x))]
    scene = Scene.from_dict({"object": {"size_m": side, "position": [0, 0, 0]},
                             "domain": {"size_m": grid * dx, "grid": grid}})
    particles = Particles(x=x, v=np.zeros(3), volume=spacing ** 3, E=E_PA, nu=NU, density=RHO, material_id=0)
    return particles, scene


def warp_arrays_bytes(solver, n: int) -> tuple[int, int]:
    """(bytes of the solver's particle-length Warp arrays, bytes of all its Warp arrays)."""
    import warp as wp

    seen: set[int] = set()
    per_particle = total = 0
    from pixie_gs.sim.state import State

    for value in vars(solver).values():
        values = value.values() if isinstance(value, dict) else value if isinstance(value, (list, tuple)) \
            else value.arrays() if isinstance(value, State) else [value]
        for arr in values:
            if isinstance(arr, wp.array) and id(arr) not in seen:
                seen.add(id(arr))
                nbytes = arr.capacity
                total += nbytes
                if arr.shape[0] == n and arr.ndim == 1:
                    per_particle += nbytes
    return per_particle, total


class KernelTimer:
    """solver.kernel_timer: time between consecutive marks, summed per kernel name (CUDA events
    on a GPU, wall clock on the CPU where Warp launches are synchronous)."""

    def __init__(self, device: str) -> None:
        import warp as wp

        self.wp, self.device = wp, device
        self.cuda = device.startswith("cuda")
        self.marks: list[tuple[str, object]] = []
        self.start()

    def _now(self):
        if self.cuda:
            ev = self.wp.Event(self.device, enable_timing=True)
            self.wp.record_event(ev)
            return ev
        return time.perf_counter()

    def start(self) -> None:
        self.marks = [("start", self._now())]

    def mark(self, name: str) -> None:
        self.marks.append((name, self._now()))

    def seconds(self) -> dict[str, float]:
        self.wp.synchronize_device(self.device)
        out: dict[str, float] = {}
        for (_, a), (name, b) in zip(self.marks, self.marks[1:]):
            dt = self.wp.get_event_elapsed_time(a, b) / 1e3 if self.cuda else b - a
            out[name] = out.get(name, 0.0) + dt
        return out


def time_warp(n_target: int, device: str, warmup: int, substeps: int, order: str = "lattice",
              p2g: str = "auto", sort_substeps: int | None = None, frames: int = 1, resort: str = "start",
              g2p_registers: int | None = None, column: dict | None = None) -> dict:
    """`column`: the column-P2G options (column_run, vector_atomics, p2g_max_registers, carry_affine,
    p2g_block_dim) for p2g "column"/"slab" (and "auto", which may choose them); the rest as the
    command-line options say. The result holds what the solver chose (p2g, column options) and
    what was asked (`requested` kind; `plain`: no option given)."""
    import warp as wp

    from pixie_gs.sim.solver import MPMSolver

    particles, scene = block_problem(n_target, shuffle=order != "lattice")
    n = len(particles)
    sort = {} if order == "sorted" else {"sort_every": 0}  # sorted: the solver's default (every frame)
    solver = MPMSolver(particles, scene, device, p2g=p2g, sort_substeps=sort_substeps,
                       resort_inside=resort == "inside", g2p_max_registers=g2p_registers, **(column or {}), **sort)
    dt = float(solver.dt)
    # step_frame(k·dt) runs k substeps of the CFL dt (the solver's own counter says how many)
    solver.step_frame(warmup * dt * (1 - 1e-6))
    wp.synchronize_device(device)
    frame_rates = []  # each timed frame alone: the same frames for every variant (same physics)
    for _ in range(frames):
        done = solver.particle_substeps
        t0, c0 = time.perf_counter(), time.process_time()
        solver.step_frame(substeps * dt * (1 - 1e-6))
        wp.synchronize_device(device)
        seconds, cpu_seconds = time.perf_counter() - t0, time.process_time() - c0
        frame_rates.append((solver.particle_substeps - done) / seconds)
    substeps = (solver.particle_substeps - done) // n
    host = dict(solver.timing)
    # the instrumented frame: per-kernel device time
    profiled = max(1, min(substeps, 50))
    timer = KernelTimer(device)
    solver.kernel_timer = timer
    solver.step_frame(profiled * dt * (1 - 1e-6))
    solver.kernel_timer = None
    kernels = {k: v / solver.substeps_last_frame for k, v in timer.seconds().items()}
    # one CFL/guard reduction and one re-sort, each timed alone
    wp.synchronize_device(device)
    t = time.perf_counter()
    for _ in range(5):
        solver.frame_stats()
    reduction_s = (time.perf_counter() - t) / 5
    t = time.perf_counter()
    solver._resort()
    wp.synchronize_device(device)
    sort_s = time.perf_counter() - t
    x = np.asarray(solver.positions())
    assert np.isfinite(x).all(), "block diverged"
    pp, total = warp_arrays_bytes(solver, n)
    chosen = dict(column or {})
    if solver.p2g_kind in ("column", "slab"):  # what the solver runs, "auto"'s choices included
        chosen.update(column_run=solver.column_run, vector_atomics=solver.vector_atomics,
                      carry_affine=solver.carry_affine, p2g_block_dim=solver.p2g_block_dim)
    plain = sort_substeps is None and resort == "start" and g2p_registers is None and not column
    return {"n": n, "order": order, "p2g": solver.p2g_kind, "requested": p2g, "plain": plain, "seconds": seconds,
            "cpu_seconds": cpu_seconds, "substeps": substeps,
            "rate": float(np.mean(frame_rates)), "frame_rates": frame_rates,
            "sort_substeps": solver.sort_substeps if solver.sort_every > 0 and solver.p2g_kind != "atomic" else None,
            "resort": resort if solver.sort_every > 0 and solver.p2g_kind != "atomic" else "",
            "g2p_registers": g2p_registers, "column": chosen, "bytes_particle_state": pp / n,
            "bytes_all_per_particle": total / n,
            "dt": dt, "host": host, "kernels": kernels, "reduction_s": reduction_s, "sort_s": sort_s}


# ---------------------------------------------------------------------------------- numpy baseline
def numpy_substep(state: dict, dx: float, dt: float, grid_n: int, mu: float, lam: float,
                  vol: float, mass: float, gravity: np.ndarray) -> None:
    """One MLS-MPM substep (P2G, grid update with gravity and sticky walls, G2P) in numpy."""
    x, v, C, F = state["x"], state["v"], state["C"], state["F"]
    inv_dx = 1.0 / dx
    base = np.floor(x * inv_dx - 0.5).astype(np.int64)
    fx = x * inv_dx - base
    w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
    U, S, Vt = np.linalg.svd(F)
    R = U @ Vt
    J = S.prod(axis=1)
    tau = 2 * mu * (F - R) @ F.transpose(0, 2, 1) + (lam * (J - 1) * J)[:, None, None] * np.eye(3)
    affine = -dt * vol * 4 * inv_dx * inv_dx * tau + mass * C
    size = grid_n ** 3
    g_m = np.zeros(size)
    g_mv = np.zeros((size, 3))
    offsets = [(i, j, k) for i in range(3) for j in range(3) for k in range(3)]
    cache = []
    for o in offsets:
        off = np.array(o)
        weight = w[o[0]][:, 0] * w[o[1]][:, 1] * w[o[2]][:, 2]
        dpos = (off - fx) * dx
        node = base + off
        flat = (node[:, 0] * grid_n + node[:, 1]) * grid_n + node[:, 2]
        cache.append((weight, dpos, flat))
        mv = weight[:, None] * (mass * v + np.einsum("nij,nj->ni", affine, dpos))
        g_m += np.bincount(flat, weight * mass, size)
        for d in range(3):
            g_mv[:, d] += np.bincount(flat, mv[:, d], size)
    has = g_m > 0
    g_v = np.zeros_like(g_mv)
    g_v[has] = g_mv[has] / g_m[has, None] + dt * gravity
    idx = np.stack(np.unravel_index(np.arange(size), (grid_n,) * 3), 1)
    wall = ((idx < 3) | (idx > grid_n - 4)).any(axis=1)
    g_v[wall] = 0.0
    new_v = np.zeros_like(v)
    new_C = np.zeros_like(C)
    for weight, dpos, flat in cache:
        gv = g_v[flat]
        new_v += weight[:, None] * gv
        new_C += 4 * inv_dx * inv_dx * weight[:, None, None] * gv[:, :, None] * dpos[:, None, :]
    state["v"], state["C"] = new_v, new_C
    state["x"] = x + dt * new_v
    state["F"] = (np.eye(3) + dt * new_C) @ F


def time_numpy(n_target: int, substeps: int) -> dict:
    particles, scene = block_problem(n_target)
    n = len(particles)
    dx = scene.dx
    origin = scene.domain_origin()
    grid_n = scene.domain.grid + 1
    mu = E_PA / (2 * (1 + NU))
    lam = E_PA * NU / ((1 + NU) * (1 - 2 * NU))
    wave = math.sqrt((lam + 2 * mu) / RHO)
    dt = 0.4 * dx / wave
    vol = float(particles.volume[0])
    state = {"x": particles.x.astype(np.float64) - origin, "v": np.zeros((n, 3)), "C": np.zeros((n, 3, 3)),
             "F": np.tile(np.eye(3), (n, 1, 1))}
    g = np.array([0.0, 0.0, -9.81])
    numpy_substep(state, dx, dt, grid_n, mu, lam, vol, vol * RHO, g)  # warm-up
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(substeps):
        numpy_substep(state, dx, dt, grid_n, mu, lam, vol, vol * RHO, g)
    seconds, cpu_seconds = time.perf_counter() - t0, time.process_time() - c0
    assert np.isfinite(state["x"]).all(), "numpy baseline diverged"
    return {"n": n, "seconds": seconds, "cpu_seconds": cpu_seconds, "substeps": substeps,
            "rate": n * substeps / seconds}


P2G_CHOICES = ("auto", "chunked", "atomic", "column", "slab")


def parse_variant(text: str) -> tuple[str, int, str, int | None, dict]:
    """'KIND[,sort=K][,inside][,g2p=R][,run=L][,novec][,p2g=R][,carry][,block=B]' → (P2G kind, re-sort
    interval (0: default), "start" or "inside", G2P register cap or None, column-P2G options:
    particles per run L, scalar instead of vector atomics, P2G register cap R, affine matrices
    carried from G2P, P2G launched in blocks of B threads)."""
    kind, *opts = text.split(",")
    k_sort, resort, regs, column = 0, "start", None, {}
    for opt in opts:
        if opt == "inside":
            resort = "inside"
        elif opt.startswith("sort="):
            k_sort = int(opt[5:])
        elif opt.startswith("g2p="):
            regs = int(opt[4:])
        elif opt.startswith("run="):
            column["column_run"] = int(opt[4:])
        elif opt == "novec":
            column["vector_atomics"] = False
        elif opt.startswith("p2g="):
            column["p2g_max_registers"] = int(opt[4:])
        elif opt == "carry":
            column["carry_affine"] = True
        elif opt.startswith("block="):
            column["p2g_block_dim"] = int(opt[6:])
        else:
            raise SystemExit(f"--variant {text!r}: unknown option {opt!r}")
    if kind not in P2G_CHOICES:
        raise SystemExit(f"--variant {text!r}: unknown P2G kind {kind!r}")
    return kind, k_sort, resort, regs, column


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--warmup", type=int, default=3, help="untimed substeps first (compilation)")
    parser.add_argument("--substeps", type=int, default=0, help="timed substeps (default: 20 cpu, 200 cuda)")
    parser.add_argument("--baseline-particles", type=int, default=20_000)
    parser.add_argument("--baseline-substeps", type=int, default=3)
    parser.add_argument("--order", nargs="+", default=["random", "sorted"], choices=["lattice", "random", "sorted"],
                        help="particle order(s) to time (see above)")
    parser.add_argument("--p2g", nargs="+", default=["auto"], choices=list(P2G_CHOICES),
                        help="P2G kernel(s): chunked (one thread per same-cell run), atomic (the plain one), "
                             "column / slab (9 / 3 threads per run of one column of cells, sliding windows, "
                             "packed grid; sorted order only), auto (solver default: on a GPU when sorting, "
                             "column carrying affine matrices, P2G blocks of 128; else atomic)")
    parser.add_argument("--sort-substeps", type=int, nargs="+", default=[0],
                        help="in-frame index re-sort interval(s) in substeps for the sorted order "
                             "(0: the solver's default)")
    parser.add_argument("--resort", nargs="+", default=["start"], choices=["start", "inside"],
                        help="sorted order, chunked/column P2G: the frame's array re-sort at the frame start (the "
                             "solver's default) or inside the frame in place of an index sort (resort_inside)")
    parser.add_argument("--variant", action="append", default=[],
                        metavar="KIND[,sort=K][,inside][,g2p=R][,run=L][,novec][,p2g=R][,carry][,block=B]",
                        help="a sorted-order variant (repeatable; replaces the --p2g x --sort-substeps x "
                             "--resort product for the sorted order): P2G kind, in-frame index re-sort "
                             "interval K, array re-sort inside the frame, G2P compiled with at most R "
                             "registers per CUDA thread; for column/slab: at most L particles per run, "
                             "scalar atomics (novec), P2G register cap, G2P leaving the next P2G's affine "
                             "matrix (carry), P2G blocks of B threads; e.g. chunked,sort=16,inside,g2p=64 or "
                             "column,run=64,carry,block=128")
    parser.add_argument("--frames", type=int, default=1,
                        help="timed frames of --substeps each, one after the other (each printed, mean reported)")
    args = parser.parse_args()

    from pixie_gs.devices import resolve_warp_device

    device = resolve_warp_device(args.device)
    substeps = args.substeps or (200 if device.startswith("cuda") else 20)
    import warp as wp

    name = wp.get_device(device).name if device.startswith("cuda") else "cpu"
    if device.startswith("cuda"):
        from pixie_gs.sim.p2g_column import vector_atomics_active

        name += f", kernels for sm_{wp.get_device(device).get_cuda_compile_arch()}, 16-byte vector atomics " + \
            ("on" if vector_atomics_active(device) else "off")
    print(f"device {device} ({name}); elastic block E={E_PA:g} Pa nu={NU} rho={RHO:g} kg/m3, "
          f"{PARTICLES_PER_CELL} particles/cell; warm-up {args.warmup}, timed {substeps} substeps")
    base = time_numpy(args.baseline_particles, args.baseline_substeps)
    print(f"baseline numpy MLS-MPM  {base['n']:>9} particles  {base['rate'] / 1e6:10.3f} M particle-substeps/s "
          f"[{base['n'] * base['substeps'] / base['cpu_seconds'] / 1e6:.3f} M per process-CPU s] "
          f"({base['substeps']} substeps in {base['seconds']:.2f} s wall, {base['cpu_seconds']:.2f} s process CPU)")
    results = []

    def details(r: dict) -> str:
        """What the row ran, after "P2G <kind>"."""
        col = r["column"]
        column = "" if r["p2g"] not in ("column", "slab") else \
            f" run {col.get('column_run', 32)}" + (" scalar atomics" if col.get("vector_atomics") is False else "") + \
            (" carry" if col.get("carry_affine") else "") + \
            (f" blocks of {col['p2g_block_dim']}" if col.get("p2g_block_dim") else "")
        return column + (f" re-sort/{r['sort_substeps']}" if r["sort_substeps"] else "") + \
            (" array sort inside" if r["resort"] == "inside" else "") + \
            (f" G2P {r['g2p_registers']} regs" if r["g2p_registers"] else "") + \
            (f" P2G {col['p2g_max_registers']} regs" if col.get("p2g_max_registers") else "")

    def is_baseline(r: dict) -> bool:  # the chunked P2G as it was the GPU default: no options
        return r["order"] == "sorted" and r["requested"] == "chunked" and r["plain"]

    def role(r: dict) -> str:
        return "default (auto) " if r["requested"] == "auto" else \
            "baseline (chunked, the previous GPU default) " if is_baseline(r) else ""

    def label(r: dict) -> str:
        return f"{role(r)}P2G {r['p2g']}{details(r)}"

    for n in args.sizes:
        runs = [(o, k, s, r, None, {}) for o in args.order for k in args.p2g for s in args.sort_substeps
                for r in args.resort if not (args.variant and o == "sorted")
                and not (o != "sorted" and k in ("column", "slab"))]  # the column P2Gs need sorting
        runs += [("sorted", *parse_variant(v)) for v in args.variant if "sorted" in args.order]
        for order, p2g, k_sort, resort, g2p_registers, column in runs:
            resorts = order == "sorted" and (p2g in ("chunked", "column", "slab")
                                             or (p2g == "auto" and device != "cpu"))
            if (k_sort != args.sort_substeps[0] or resort != args.resort[0]) and not resorts and g2p_registers is None:
                continue  # no in-frame re-sort to vary
            r = time_warp(n, device, args.warmup, substeps, order, p2g, k_sort or None, args.frames, resort,
                          g2p_registers, column)
            results.append(r)
            cpu_rate = f" [{r['n'] * r['substeps'] / r['cpu_seconds'] / 1e6:.3f} M per process-CPU s]" \
                if device == "cpu" and r["cpu_seconds"] > 0 else ""
            frames = "" if len(r["frame_rates"]) < 2 else \
                " (frames: " + " / ".join(f"{x / 1e6:.4g}" for x in r["frame_rates"]) + ", mean)"
            print(f"warp {device:<6} {r['n']:>9} particles {order:<7} {role(r)}P2G {r['p2g']:<7}"
                  f"{details(r)} "
                  f"{r['rate'] / 1e6:10.3f} M particle-substeps/s{frames}"
                  f"{cpu_rate} ({r['substeps']} substeps in one step_frame, {r['seconds']:.3f} s wall, "
                  f"{r['cpu_seconds']:.2f} s process CPU, dt {r['dt']:.2e} s)  "
                  f"memory {r['bytes_particle_state']:.0f} B/particle state, {r['bytes_all_per_particle']:.0f} B/particle "
                  f"incl. grid  ratio vs numpy baseline {r['rate'] / base['rate']:.1f}x")
            k, h = r["kernels"], r["host"]
            per_sub = sum(k.values())
            print(f"    per substep (device): P2G {k.get('p2g', 0) * 1e3:.3f} ms, grid {k.get('grid', 0) * 1e3:.3f} ms, "
                  f"G2P {k.get('g2p', 0) * 1e3:.3f} ms, in-frame index sort {k.get('sort', 0) * 1e3:.3f} ms, "
                  f"in-frame array sort {k.get('resort', 0) * 1e3:.3f} ms "
                  f"= {per_sub * 1e3:.3f} ms "
                  f"(kernels alone: {r['n'] / per_sub / 1e6:.1f} M particle-substeps/s)")
            print(f"    timed frame, host seconds: re-sort {h['sort_s']:.4f}, CFL reduction {h['stats_s']:.4f}, "
                  f"issuing {r['substeps']} substeps {h['launch_s']:.4f}, guard incl. waiting for the device "
                  f"{h['guard_s']:.4f}; one reduction {r['reduction_s'] * 1e3:.3f} ms, one re-sort "
                  f"{r['sort_s'] * 1e3:.2f} ms (peak +{2 * 8 + 36} B/particle while sorting)")
    for order in args.order:
        rows = [r for r in results if r["order"] == order and r["p2g"] == results[0]["p2g"]
                and r["sort_substeps"] == results[0]["sort_substeps"]]
        if len(rows) >= 2:
            a, b = rows[0], rows[-1]
            print(f"scaling {a['n']} -> {b['n']} particles ({order}): throughput ratio {b['rate'] / a['rate']:.2f}")
    for n in sorted({r["n"] for r in results}):  # variants against the baseline, same run, same frames
        same = [r for r in results if r["n"] == n and r["order"] == "sorted"]
        if len(same) < 2:
            continue
        ref = next((r for r in same if is_baseline(r)), same[0])  # the chunked P2G, else the first row
        for r in same:
            if r is not ref:
                print(f"variant vs baseline ({n} particles, sorted): {label(r)} {r['rate'] / 1e6:.4g} M / "
                      f"{label(ref)} {ref['rate'] / 1e6:.4g} M = {r['rate'] / ref['rate']:.3f}")
        default = next((r for r in same if r["requested"] == "auto"), None)
        if default is not None and default is not ref and is_baseline(ref) and device.startswith("cuda"):
            print(f"new default vs baseline ({n} particles, sorted, mean of {len(default['frame_rates'])} frames): "
                  f"{label(default)} {default['rate'] / 1e6:.4g} M / chunked {ref['rate'] / 1e6:.4g} M = "
                  f"{default['rate'] / ref['rate']:.3f}")
    if device.startswith("cuda"):
        for r in results:
            if r["order"] != "lattice" and r["n"] >= 900_000:
                goal = 2500e6 if r["n"] < 2_000_000 else 2400e6
                print(f"issue 14 goal >= {goal / 1e6:.0f} M particle-substeps/s, {r['order']} input order, {label(r)}, "
                      f"{r['n']} particles: {'MET' if r['rate'] >= goal else 'NOT MET'} ({r['rate'] / 1e6:.1f} M)")


if __name__ == "__main__":
    main()
