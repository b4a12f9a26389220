"""Warp kernels of one MLS-MPM substep for a BATCH of independent runs in one launch.

K runs (candidate parameter sets of one object, or different objects on the same grid) form one
particle set; `run[p]` says which run particle p belongs to, and each run has its own grid
(the grid arrays are 4-D: run, i, j, k), its own substep dt (s) and count, and its own scene
scalars (gravity, wind, damping, drag, ground). The substep index and the frame's start time are
read from 1-element device arrays, so a substep's launches never change their arguments (a
CUDA graph can replay them). A run whose frame is done (`substep ≥ n_sub[r]`)
or that has failed sits out (its particles and nodes are skipped), so every run takes exactly
the substeps it would take alone. The arithmetic follows sim/kernels.py (p2g, grid_update, g2p)
term by term, so on the CPU (where Warp runs a launch's threads in order) a batched run gives
the same numbers as the unbatched solver with the particles in the same order; the tests check
that against separate MPMSolver runs.
"""
from __future__ import annotations

import warp as wp

from .constitutive import MaterialParams, update_material
from .kernels import GridInfo, advected_position, bspline_weights, gather_velocity, mls_affine, stencil_of
from .reduce import fails_guard


@wp.func
def run_active(r: int, substep: wp.array(dtype=wp.int32), n_sub: wp.array(dtype=wp.int32)) -> bool:
    return substep[0] < n_sub[r]


@wp.kernel
def advance_substep(substep: wp.array(dtype=wp.int32), value: int, add: int):
    """substep[0] ← substep[0]·add + value (add 0: set; add 1, value 1: next substep)."""
    substep[0] = substep[0] * add + value


@wp.kernel
def p2g_batched(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
                stress: wp.array(dtype=wp.mat33), volume: wp.array(dtype=float), mass: wp.array(dtype=float),
                fixed: wp.array(dtype=wp.int32), run: wp.array(dtype=wp.int32), grid: GridInfo,
                dt_run: wp.array(dtype=float), n_sub: wp.array(dtype=wp.int32), substep: wp.array(dtype=wp.int32),
                grid_mass: wp.array4d(dtype=float), grid_momentum: wp.array4d(dtype=wp.vec3),
                grid_fixed: wp.array4d(dtype=float)):
    """kernels.p2g into the grid of the particle's run."""
    p = wp.tid()
    r = run[p]
    if not run_active(r, substep, n_sub):
        return
    dt = dt_run[r]
    base, fx = stencil_of(x[p], grid)
    wx = bspline_weights(fx[0])
    wy = bspline_weights(fx[1])
    wz = bspline_weights(fx[2])
    m = mass[p]
    is_fixed = fixed[p]
    affine = mls_affine(dt, volume[p], stress[p], m, C[p], grid)
    mv = m * v[p]
    for i in range(3):
        for j in range(3):
            for k in range(3):
                w = wx[i] * wy[j] * wz[k]
                dpos = (wp.vec3(float(i), float(j), float(k)) - fx) * grid.dx
                gi = base[0] + i
                gj = base[1] + j
                gk = base[2] + k
                wp.atomic_add(grid_momentum, r, gi, gj, gk, w * (mv + affine * dpos))
                wp.atomic_add(grid_mass, r, gi, gj, gk, w * m)
                if is_fixed != 0:
                    wp.atomic_add(grid_fixed, r, gi, gj, gk, w)


@wp.struct
class RunForces:
    """Per-run scene scalars (arrays of K), winds flattened: run r owns winds
    wind_first[r] ≤ w < wind_first[r+1]."""

    gravity: wp.array(dtype=wp.vec3)  # m/s²
    damping: wp.array(dtype=float)  # 1/s
    air_drag: wp.array(dtype=float)  # 1/m
    ground_enabled: wp.array(dtype=wp.int32)
    ground_height: wp.array(dtype=float)  # m
    friction: wp.array(dtype=float)  # Coulomb μ
    wind_first: wp.array(dtype=wp.int32)
    wind_acc: wp.array(dtype=wp.vec3)  # m/s²
    wind_lo: wp.array(dtype=wp.vec3)  # m
    wind_hi: wp.array(dtype=wp.vec3)  # m
    wind_timing: wp.array(dtype=wp.vec4)  # start_s, end_s, gust amplitude, gust frequency (Hz)


@wp.kernel
def grid_update_batched(grid_mass: wp.array4d(dtype=float), grid_momentum: wp.array4d(dtype=wp.vec3),
                        grid_fixed: wp.array4d(dtype=float), grid_velocity: wp.array4d(dtype=wp.vec3),
                        grid: GridInfo, box_lo: wp.vec3i, dt_run: wp.array(dtype=float),
                        n_sub: wp.array(dtype=wp.int32), substep: wp.array(dtype=wp.int32),
                        frame_start_s: wp.array(dtype=wp.float64),
                        dt_run64: wp.array(dtype=wp.float64), forces: RunForces, sticky_walls: int, boundary: int):
    """kernels.grid_update on each active run's grid with that run's forces; time of run r is
    frame_start_s + substep · dt_r (in float64, as the unbatched solver computes it on the host)."""
    r, a, b, c = wp.tid()
    if not run_active(r, substep, n_sub):
        return
    dt = dt_run[r]
    time_s = float(frame_start_s[0] + wp.float64(substep[0]) * dt_run64[r])
    i = a + box_lo[0]
    j = b + box_lo[1]
    k = c + box_lo[2]
    m = grid_mass[r, i, j, k]
    held = grid_fixed[r, i, j, k]
    vel = wp.vec3(0.0)
    if m > 0.0 and held <= 0.0:
        vel = grid_momentum[r, i, j, k] / m
        node = grid.origin + wp.vec3(float(i), float(j), float(k)) * grid.dx
        acc = forces.gravity[r]
        for w in range(forces.wind_first[r], forces.wind_first[r + 1]):
            timing = forces.wind_timing[w]
            lo = forces.wind_lo[w]
            hi = forces.wind_hi[w]
            inside = node[0] >= lo[0] and node[1] >= lo[1] and node[2] >= lo[2]
            inside = inside and node[0] <= hi[0] and node[1] <= hi[1] and node[2] <= hi[2]
            if inside and time_s >= timing[0] and time_s < timing[1]:
                gust = 1.0 + timing[2] * wp.sin(2.0 * wp.pi * timing[3] * time_s)
                acc = acc + gust * forces.wind_acc[w]
        vel = vel + dt * acc
        vel = vel * wp.exp(-forces.damping[r] * dt)
        vel = vel / (1.0 + forces.air_drag[r] * wp.length(vel) * dt)
        on_ground = node[2] <= forces.ground_height[r] or k < boundary
        if forces.ground_enabled[r] != 0 and on_ground and vel[2] < 0.0:
            vn = -vel[2]
            vt = wp.vec3(vel[0], vel[1], 0.0)
            speed_t = wp.length(vt)
            friction = forces.friction[r]
            if speed_t <= friction * vn:
                vel = wp.vec3(0.0)
            else:
                vel = vt * (1.0 - friction * vn / speed_t)
        idx = wp.vec3i(i, j, k)
        for d in range(3):
            low = idx[d] < boundary
            high = idx[d] >= grid.dims[d] - boundary
            if low or high:
                if sticky_walls != 0:
                    vel = wp.vec3(0.0)
                elif (low and vel[d] < 0.0) or (high and vel[d] > 0.0):
                    vel[d] = 0.0
    grid_velocity[r, i, j, k] = vel
    grid_mass[r, i, j, k] = 0.0
    grid_momentum[r, i, j, k] = wp.vec3(0.0)
    grid_fixed[r, i, j, k] = 0.0


@wp.kernel
def g2p_batched(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
                F: wp.array(dtype=wp.mat33), mu: wp.array(dtype=float), lam: wp.array(dtype=float),
                yield_stress: wp.array(dtype=float), material: wp.array(dtype=wp.int32), Jp: wp.array(dtype=float),
                fixed: wp.array(dtype=wp.int32), run: wp.array(dtype=wp.int32), grid: GridInfo,
                mp: MaterialParams, dt_run: wp.array(dtype=float), n_sub: wp.array(dtype=wp.int32),
                substep: wp.array(dtype=wp.int32),
                grid_velocity: wp.array4d(dtype=wp.vec3), stress: wp.array(dtype=wp.mat33)):
    """kernels.g2p from the grid of the particle's run."""
    p = wp.tid()
    r = run[p]
    if not run_active(r, substep, n_sub):
        return
    if fixed[p] != 0:
        v[p] = wp.vec3(0.0)
        C[p] = wp.mat33(0.0)
        return
    dt = dt_run[r]
    new_v, new_C = gather_velocity(x[p], grid, grid_velocity[r])  # the run's 3-D grid, a view
    v[p] = new_v
    C[p] = new_C
    x[p] = advected_position(x[p], new_v, dt, grid)
    Fn = (wp.identity(n=3, dtype=float) + dt * new_C) * F[p]
    Fn, Jp_new, tau = update_material(Fn, new_C, mu[p], lam[p], material[p], yield_stress[p], Jp[p], dt, mp)
    F[p] = Fn
    Jp[p] = Jp_new
    stress[p] = tau


@wp.kernel
def run_stats(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), F: wp.array(dtype=wp.mat33),
              Jp: wp.array(dtype=float), material: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
              wave_c: wp.array(dtype=float), run: wp.array(dtype=wp.int32), alive: wp.array(dtype=wp.int32),
              snow_hardening: float, v_limit: wp.array(dtype=float), max_stretch: float,
              maxima: wp.array2d(dtype=float), bad: wp.array2d(dtype=wp.int32)):
    """reduce.particle_stats per run: maxima[r] ← (fastest moving particle m/s, fastest hardened
    snow wave m/s); bad[r, material] += 1 per particle failing the guard (speed > v_limit[r])."""
    p = wp.tid()
    r = run[p]
    if alive[r] == 0:
        return
    speed = wp.length(v[p])
    if fails_guard(x[p], speed, F[p], v_limit[r], max_stretch):
        wp.atomic_add(bad, r, material[p], 1)
    elif fixed[p] == 0:
        if speed > 0.0:
            wp.atomic_max(maxima, r, 0, speed)
        if material[p] == 5:  # snow (pixie_gs.materials.SNOW)
            wave = wave_c[p] * wp.sqrt(wp.exp(snow_hardening * wp.max(0.0, 1.0 - Jp[p])))
            if wave > 0.0:
                wp.atomic_max(maxima, r, 1, wave)


# ---------------------------------------------------------------------------------- frames on the device
# A whole frame with nothing read back (BatchedSolver.frames_on_device): the substep plan that
# BatchedSolver._plan makes on the host, made here from the last frame's statistics in the same
# float64 operations; the substep loop as a device-side while loop; the divergence guard; the
# tracked points copied into a history. Every per-frame figure the host needs comes back once, at
# the end. One thread walks the K runs in order (K ≤ 64: nothing to parallelise).


@wp.kernel
def plan_frame(maxima: wp.array2d(dtype=float), alive: wp.array(dtype=wp.int32),
               c_static: wp.array(dtype=wp.float64), has_snow: wp.array(dtype=wp.int32),
               accel_dt: wp.array(dtype=wp.float64), frame_dt: wp.float64, cfl_dx: wp.float64,
               vcfl_dx: wp.float64, dx: wp.float64, max_sub: int, far: float,
               n_sub: wp.array(dtype=wp.int32), dt_run: wp.array(dtype=float), dt_run64: wp.array(dtype=wp.float64),
               v_limit: wp.array(dtype=float), v_limit64: wp.array(dtype=wp.float64),
               over_budget: wp.array(dtype=wp.int32), last_dt: wp.array(dtype=wp.float64),
               substep: wp.array(dtype=wp.int32), n_max: wp.array(dtype=wp.int32), cond: wp.array(dtype=wp.int32),
               total: wp.array(dtype=wp.int32)):
    """BatchedSolver._plan for every run (accel_dt = accel · frame_dt, cfl_dx = cfl · dx and
    vcfl_dx = velocity_cfl · dx computed on the host, as there), then the frame's dt, velocity limit,
    substep counter and loop condition (n_max > 0); `total` counts the substeps launched."""
    top = int(0)
    zero = wp.float64(0.0)
    for r in range(alive.shape[0]):
        n = int(0)
        if alive[r] != 0:
            c = c_static[r]
            if has_snow[r] != 0:
                c = wp.max(c, wp.float64(maxima[r, 1]))
            n_elastic = wp.float64(1.0)
            if c != zero:
                dt = cfl_dx / c
                if wp.isfinite(dt):
                    n_elastic = wp.ceil(frame_dt / dt)
            if n_elastic > wp.float64(max_sub):
                alive[r] = 0  # over the budget: the caller runs it alone
                over_budget[r] = 1
            else:
                v_bound = wp.float64(maxima[r, 0]) + accel_dt[r]
                n_velocity = wp.ceil(frame_dt * v_bound / vcfl_dx)
                n = int(wp.min(wp.max(wp.max(wp.float64(1.0), n_elastic), n_velocity), wp.float64(max_sub)))
        n_sub[r] = n
        if n > 0:
            dts = frame_dt / wp.float64(n)
            dt_run[r] = float(dts)
            dt_run64[r] = dts
            limit = dx / dts
            v_limit[r] = float(limit)
            v_limit64[r] = limit
            last_dt[r] = dts
        else:
            dt_run[r] = 0.0
            dt_run64[r] = zero
            v_limit[r] = far
            v_limit64[r] = wp.float64(far)
        top = wp.max(top, n)
    substep[0] = 0
    n_max[0] = top
    cond[0] = wp.where(top > 0, 1, 0)
    total[0] = total[0] + top


@wp.kernel
def next_substep(substep: wp.array(dtype=wp.int32), n_max: wp.array(dtype=wp.int32), cond: wp.array(dtype=wp.int32)):
    """substep += 1; the loop goes on while substep < n_max."""
    s = substep[0] + 1
    substep[0] = s
    cond[0] = wp.where(s < n_max[0], 1, 0)


@wp.kernel
def guard_frame(bad: wp.array2d(dtype=wp.int32), alive: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.int32),
                v_limit64: wp.array(dtype=wp.float64), err_frame: wp.array(dtype=wp.int32),
                err_counts: wp.array2d(dtype=wp.int32), err_limit: wp.array(dtype=wp.float64)):
    """BatchedSolver._guard: a live run with particles failing the guard stops; the frame number
    (after this frame), its counts per material and its velocity limit are kept for the message."""
    for r in range(alive.shape[0]):
        if alive[r] != 0:
            total = int(0)
            for m in range(bad.shape[1]):
                total += bad[r, m]
            if total > 0:
                alive[r] = 0
                err_frame[r] = frame[0] + 1
                err_limit[r] = v_limit64[r]
                for m in range(bad.shape[1]):
                    err_counts[r, m] = bad[r, m]


@wp.kernel
def record_points(x: wp.array(dtype=wp.vec3), slots: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.int32),
                  history: wp.array2d(dtype=wp.vec3)):
    """history[frame + 1, j] = x[slots[j]] (the frame being finished; rows are frames)."""
    j = wp.tid()
    history[frame[0] + 1, j] = x[slots[j]]


@wp.kernel
def end_frame(frame: wp.array(dtype=wp.int32), frame_start: wp.array(dtype=wp.float64), frame_dt: wp.float64):
    """frame += 1; the next frame starts frame_dt later (the host's time_s + frame_dt, in float64)."""
    frame[0] = frame[0] + 1
    frame_start[0] = frame_start[0] + frame_dt
