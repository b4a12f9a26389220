"""Make the independent-engine measurement fixtures of `pixie diagnose` (tests/data/independent/).

The "measured" tracks of these fixtures come from an MLS-MPM written here in Taichi's language
(https://pypi.org/project/taichi/, run on the CPU) — NOT from pixie-gs's Warp solver — so that
diagnose is tested against a world its own simulator does not reproduce exactly: different
particle sampling (a regular lattice, 8 particles per cell, exact volumes), a finer grid,
explicit/implicit choices of its own for damping and drag, its own contact and plasticity code.

Scene (world metres, z up): the two-part jelly of `pixie_gs.diagnose.synthetic.two_part_block`
(body 0.2 × 0.2 × 0.1, head 0.1 × 0.1 × 0.1 splat units on top), scaled ×(0.3 / extent) so its
longest side is 0.3 m, bottom centre at (−0.15, 0, 0.1) m, tossed at t = 0 with velocity
(1.2, 0, 0.8) m/s onto a ground plane z = 0 (Coulomb μ = 0.3), gravity 9.81 m/s².
Body E 2 kPa, ρ 150 kg/m³; head E 4 kPa, ρ 100 kg/m³; ν 0.35; fixed-corotated elasticity.
Each fixture switches on one hidden effect (or none). The tracked points are passive tracers at
the rest positions of 5 % of the model's Gaussians (two_part_block(2000, seed=0)); they move with
the grid velocity like the material points. Positions are written in the splat's coordinates with
1 mm (1e-3 splat units) white noise, 17 frames at 25 fps, no ids (diagnose matches them).

    pip install taichi==1.7.4
    python scripts/make_independent_tracks.py [--grid 128] [--only nothing,air_drag] [--out tests/data/independent]
    python scripts/make_independent_tracks.py --convergence   # the truth's own grid convergence
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

GRAVITY = 9.81
TOSS_VELOCITY = (1.2, 0.0, 0.8)            # m/s at t = 0
OBJECT_SIZE_M, OBJECT_BOTTOM = 0.3, (-0.15, 0.0, 0.1)
BASE_FRICTION = 0.3
E_PA, RHO, NU = (2000.0, 4000.0), (150.0, 100.0), 0.35   # (body, head)
FRAMES, FPS = 17, 25.0
N_GAUSSIANS, TRACK_FRACTION, NOISE = 2000, 0.05, 1e-3
DOMAIN_LO = np.array([-0.85, -0.85, -0.05])               # m; the box is DOMAIN_SIZE on a side in x, y
DOMAIN_SIZE = 1.7                                          # m (z: half of it)

# name -> hidden effect settings of the independent engine (true values)
CASES: dict[str, dict] = {
    "nothing": {},
    "viscous_damping": {"damping": 2.0},                 # 1/s, a = −c v
    "air_drag": {"drag": 2.5},                           # 1/m, a = −k |v| v
    "ground_friction": {"friction": 0.1},                # μ (instead of 0.3): it slides further
    "wind": {"wind": (0.0, 2.0, 0.0)},                   # m/s² in world axes
    "part_stiffness": {"E_scale_head": 0.2},             # head 5× softer than believed
    "part_density": {"density_scale_head": 4.0},         # head 4× heavier
    "plastic_yield": {"yield_body_pa": 20.0},            # von Mises yield of the body (Pa)
    "anchored_part": {"anchor_body": True},              # body glued to the ground
    "part_stiffness_body": {"E_scale_body": 0.2},        # body 5× softer than believed
}


def model_geometry():
    """The model's Gaussians (splat units), part ids and the splat → world placement."""
    from pixie_gs.diagnose.synthetic import two_part_block

    cloud = two_part_block(n=N_GAUSSIANS, seed=0)
    means = cloud.means.astype(np.float64)
    lo, hi = means.min(0), means.max(0)
    scale = OBJECT_SIZE_M / float((hi - lo).max())
    bottom = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]) * scale
    offset = np.asarray(OBJECT_BOTTOM) - bottom
    return means, cloud.get("part_id").astype(np.int64), scale, offset


def lattice(scale: float, offset: np.ndarray, dx: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Material points on a lattice of 2×2×2 per cell filling body and head (world m) → (x, part, volume m³)."""
    h = dx / 2.0
    boxes = [((-0.1, -0.1, 0.0), (0.1, 0.1, 0.1)), ((-0.05, -0.05, 0.1), (0.05, 0.05, 0.2))]
    xs, parts = [], []
    for part, (lo, hi) in enumerate(boxes):
        lo_w = np.asarray(lo) * scale + offset
        hi_w = np.asarray(hi) * scale + offset
        axes = [np.arange(lo_w[d] + h / 2, hi_w[d], h) for d in range(3)]
        g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        xs.append(g)
        parts.append(np.full(len(g), part))
    return np.concatenate(xs), np.concatenate(parts), h ** 3


def run_engine(effect: dict, grid: int, tracers_world: np.ndarray, scale: float, offset: np.ndarray,
               verbose: bool = True) -> np.ndarray:
    """Simulate the toss in Taichi with `effect` switched on → tracer positions (FRAMES, M, 3) world m."""
    import taichi as ti

    ti.init(arch=ti.cpu, default_fp=ti.f32, offline_cache=False, log_level=ti.WARN)
    dx = DOMAIN_SIZE / grid
    inv_dx = 1.0 / dx
    xs, part, vol = lattice(scale, offset, dx)
    n, m = len(xs), len(tracers_world)
    E = np.array(E_PA)[part] * np.where(part == 1, effect.get("E_scale_head", 1.0), effect.get("E_scale_body", 1.0))
    rho = np.array(RHO)[part] * np.where(part == 1, effect.get("density_scale_head", 1.0), 1.0)
    mu_np = E / (2 * (1 + NU))
    lam_np = E * NU / ((1 + NU) * (1 - 2 * NU))
    ys_np = np.where(part == 0, effect.get("yield_body_pa", 1e30), 1e30)
    anchored_np = (part == 0) & bool(effect.get("anchor_body", False))
    c_wave = float(np.sqrt((lam_np + 2 * mu_np) / rho).max())
    dt_max = min(0.3 * dx / c_wave, 0.15 * dx / 3.0)
    sub = int(math.ceil(1.0 / FPS / dt_max))
    dt = 1.0 / FPS / sub
    damping = float(effect.get("damping", 0.0))
    drag = float(effect.get("drag", 0.0))
    friction = float(effect.get("friction", BASE_FRICTION))
    wind = effect.get("wind", (0.0, 0.0, 0.0))
    acc = ti.Vector([wind[0], wind[1], wind[2] - GRAVITY])
    nz = grid // 2
    lo = ti.Vector(list(DOMAIN_LO))

    x = ti.Vector.field(3, float, n)
    v = ti.Vector.field(3, float, n)
    C = ti.Matrix.field(3, 3, float, n)
    F = ti.Matrix.field(3, 3, float, n)
    mass = ti.field(float, n)
    mu = ti.field(float, n)
    lam = ti.field(float, n)
    ys = ti.field(float, n)
    anchored = ti.field(int, n)
    tx = ti.Vector.field(3, float, m)
    gv = ti.Vector.field(3, float, (grid + 1, grid + 1, nz + 1))
    gm = ti.field(float, (grid + 1, grid + 1, nz + 1))
    ga = ti.field(float, (grid + 1, grid + 1, nz + 1))

    x.from_numpy(xs.astype(np.float32))
    v0 = np.where(anchored_np[:, None], 0.0, np.asarray(TOSS_VELOCITY)[None]).astype(np.float32)
    v.from_numpy(v0)
    F.from_numpy(np.tile(np.eye(3, dtype=np.float32), (n, 1, 1)))
    C.from_numpy(np.zeros((n, 3, 3), np.float32))
    mass.from_numpy((rho * vol).astype(np.float32))
    mu.from_numpy(mu_np.astype(np.float32))
    lam.from_numpy(lam_np.astype(np.float32))
    ys.from_numpy(ys_np.astype(np.float32))
    anchored.from_numpy(anchored_np.astype(np.int32))
    tx.from_numpy(tracers_world.astype(np.float32))

    @ti.func
    def weights(fx):
        return [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]

    @ti.kernel
    def p2g():
        for I in ti.grouped(gm):
            gv[I] = ti.Vector([0.0, 0.0, 0.0])
            gm[I] = 0.0
            ga[I] = 0.0
        for p in x:
            Xp = (x[p] - lo) * inv_dx
            base = ti.cast(Xp - 0.5, int)
            fx = Xp - base
            w = weights(fx)
            U, sig, V = ti.svd(F[p])
            R = U @ V.transpose()
            J = F[p].determinant()
            tau = 2.0 * mu[p] * (F[p] - R) @ F[p].transpose() + ti.Matrix.identity(float, 3) * lam[p] * J * (J - 1.0)
            affine = -dt * vol * 4.0 * inv_dx * inv_dx * tau + mass[p] * C[p]
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                off = ti.Vector([i, j, k])
                dpos = (off - fx) * dx
                wt = w[i][0] * w[j][1] * w[k][2]
                gv[base + off] += wt * (mass[p] * v[p] + affine @ dpos)
                gm[base + off] += wt * mass[p]
                if anchored[p] != 0:
                    ga[base + off] += wt

    @ti.kernel
    def grid_op():
        for I in ti.grouped(gm):
            if gm[I] > 0:
                vel = gv[I] / gm[I]
                vel += dt * acc
                vel /= 1.0 + damping * dt                       # a = −c v, implicit Euler
                vel *= ti.max(0.0, 1.0 - dt * drag * vel.norm())  # a = −k |v| v, explicit
                if ga[I] > 0:
                    vel = ti.Vector([0.0, 0.0, 0.0])
                z = lo[2] + I[2] * dx
                if z <= 0.0 and vel[2] < 0.0:                   # ground plane z = 0, Coulomb
                    vn = -vel[2]
                    vt = ti.Vector([vel[0], vel[1], 0.0])
                    st = vt.norm()
                    if st <= friction * vn:
                        vel = ti.Vector([0.0, 0.0, 0.0])
                    else:
                        vel = vt * (1.0 - friction * vn / st)
                for d in ti.static(range(3)):                   # slip walls
                    top = grid if d < 2 else nz
                    if I[d] < 2 and vel[d] < 0:
                        vel[d] = 0.0
                    if I[d] > top - 2 and vel[d] > 0:
                        vel[d] = 0.0
                gv[I] = vel

    @ti.kernel
    def g2p():
        for p in x:
            if anchored[p] != 0:
                continue
            Xp = (x[p] - lo) * inv_dx
            base = ti.cast(Xp - 0.5, int)
            fx = Xp - base
            w = weights(fx)
            new_v = ti.Vector.zero(float, 3)
            new_C = ti.Matrix.zero(float, 3, 3)
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                off = ti.Vector([i, j, k])
                dpos = (off - fx) * dx
                wt = w[i][0] * w[j][1] * w[k][2]
                gvel = gv[base + off]
                new_v += wt * gvel
                new_C += 4.0 * inv_dx * inv_dx * wt * gvel.outer_product(dpos)
            v[p] = new_v
            C[p] = new_C
            x[p] += dt * new_v
            Fn = (ti.Matrix.identity(float, 3) + dt * new_C) @ F[p]
            if ys[p] < 1e29:                                    # von Mises on Hencky strain
                U, sig, V = ti.svd(Fn)
                e = ti.Vector([ti.log(ti.max(sig[0, 0], 1e-6)), ti.log(ti.max(sig[1, 1], 1e-6)),
                               ti.log(ti.max(sig[2, 2], 1e-6))])
                e_dev = e - e.sum() / 3.0
                nrm = e_dev.norm()
                dgamma = nrm - ti.sqrt(2.0 / 3.0) * ys[p] / (2.0 * mu[p])
                if dgamma > 0 and nrm > 1e-12:
                    e -= dgamma / nrm * e_dev
                    Fn = U @ ti.Matrix([[ti.exp(e[0]), 0, 0], [0, ti.exp(e[1]), 0], [0, 0, ti.exp(e[2])]]) \
                        @ V.transpose()
            F[p] = Fn
        for q in tx:
            Xp = (tx[q] - lo) * inv_dx
            base = ti.cast(Xp - 0.5, int)
            fx = Xp - base
            w = weights(fx)
            new_v = ti.Vector.zero(float, 3)
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                off = ti.Vector([i, j, k])
                new_v += w[i][0] * w[j][1] * w[k][2] * gv[base + off]
            tx[q] += dt * new_v

    out = np.zeros((FRAMES, m, 3))
    out[0] = tracers_world
    start = time.perf_counter()
    for f in range(1, FRAMES):
        for _ in range(sub):
            p2g()
            grid_op()
            g2p()
        out[f] = tx.to_numpy()
        if not np.isfinite(out[f]).all():
            raise RuntimeError(f"independent engine diverged at frame {f}")
    if verbose:
        print(f"  taichi: grid {grid} (dx {100 * dx:.2f} cm), {n} particles, {sub} substeps/frame, "
              f"{time.perf_counter() - start:.1f} s", flush=True)
    return out


def tracked_points(means: np.ndarray) -> np.ndarray:
    """Ids of the tracked Gaussians: 5 % of them, fixed seed."""
    rng = np.random.default_rng(11)
    return np.sort(rng.choice(len(means), int(round(TRACK_FRACTION * len(means))), replace=False))


def make_case(name: str, grid: int, out_dir: Path, seed: int) -> Path:
    import taichi as ti

    means, _, scale, offset = model_geometry()
    ids = tracked_points(means)
    tracers = means[ids] * scale + offset
    world = run_engine(CASES[name], grid, tracers, scale, offset)
    splat = (world - offset) / scale
    rng = np.random.default_rng(seed)
    noisy = splat + rng.normal(0.0, NOISE, splat.shape)
    meta = {"engine": f"taichi {'.'.join(map(str, ti.__version__))} (CPU), MLS-MPM written in "
                      "scripts/make_independent_tracks.py", "grid": grid, "dx_m": DOMAIN_SIZE / grid,
            "particles_per_cell": 8, "hidden": name, "effect": CASES[name], "noise_splat_units": NOISE,
            "seed": seed, "fps": FPS, "frames": FRAMES, "toss_velocity_m_s": TOSS_VELOCITY,
            "base_friction": BASE_FRICTION, "E_pa": E_PA, "density": RHO, "nu": NU,
            "model": f"two_part_block(n={N_GAUSSIANS}, seed=0)", "splat_to_world_scale": scale}
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{name}.npz"
    np.savez_compressed(path, t=np.arange(FRAMES) / FPS, x=noisy.astype(np.float32),
                        source_ids=ids.astype(np.int32), meta=np.array(json.dumps(meta)))
    return path


def convergence(grids: list[int]) -> None:
    """RMS difference (mm, world) of the nothing-hidden tracks between grids of the truth engine."""
    means, _, scale, offset = model_geometry()
    ids = tracked_points(means)
    tracers = means[ids] * scale + offset
    runs = {g: run_engine({}, g, tracers, scale, offset) for g in grids}
    finest = runs[max(grids)]
    for g in grids:
        d = np.sqrt(np.mean(np.sum((runs[g] - finest) ** 2, axis=2)))
        print(f"grid {g} (dx {100 * DOMAIN_SIZE / g:.2f} cm): RMS vs grid {max(grids)}: {1000 * d:.2f} mm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, default=128, help="cells along x and y (dx = 1.7 m / grid)")
    ap.add_argument("--only", help="comma-separated case names (default: all)")
    ap.add_argument("--out", default="tests/data/independent")
    ap.add_argument("--convergence", action="store_true", help="only print the truth's grid convergence")
    args = ap.parse_args()
    if args.convergence:
        convergence([48, 64, 96, 128])
        return
    names = args.only.split(",") if args.only else list(CASES)
    for i, name in enumerate(names):
        print(f"{name}:", flush=True)
        print(f"  wrote {make_case(name, args.grid, Path(args.out), seed=100 + list(CASES).index(name))}")


if __name__ == "__main__":
    main()
