"""Warp kernels of one MLS-MPM/APIC substep with quadratic B-splines (Hu et al. 2018).

One Warp module (compiled once per machine): P2G scatters mass, momentum and stress; the grid
update turns momentum into velocity and applies forces and boundaries (and clears the scatter
buffers for the next substep); G2P gathers velocity and its gradient, moves particles, updates
F ← (I + dt·C)·F, applies the return mapping of sim/constitutive.py and stores the stress.
Grid node (i, j, k) sits at world position origin + (i, j, k)·dx.
"""
from __future__ import annotations

import warp as wp

from .constitutive import MaterialParams, update_material


@wp.struct
class GridInfo:
    origin: wp.vec3  # world position (m) of node (0, 0, 0)
    dx: float  # m
    inv_dx: float  # 1/m
    dims: wp.vec3i  # node counts


@wp.func
def bspline_weights(fx: float) -> wp.vec3:
    """Quadratic B-spline weights of the 3 nodes base, base+1, base+2 (fx = x/dx − base ∈ [0.5, 1.5))."""
    return wp.vec3(0.5 * (1.5 - fx) * (1.5 - fx), 0.75 - (fx - 1.0) * (fx - 1.0), 0.5 * (fx - 0.5) * (fx - 0.5))


@wp.func
def stencil_of(xp: wp.vec3, grid: GridInfo):
    """Lowest node (base) of the 3×3×3 stencil around world position `xp` and the position
    relative to it in cells (fx ∈ [0.5, 1.5)³), shared by P2G and G2P. The base is clamped into the grid:
    the walls keep every finite particle inside, and a NaN one (a solver fault the frame's divergence guard
    then reports) must not index outside the arrays (a segfault on a CPU, stop 53)."""
    xg = (xp - grid.origin) * grid.inv_dx
    base = wp.vec3i(wp.clamp(int(xg[0] - 0.5), 0, grid.dims[0] - 3), wp.clamp(int(xg[1] - 0.5), 0, grid.dims[1] - 3),
                    wp.clamp(int(xg[2] - 0.5), 0, grid.dims[2] - 3))
    return base, xg - wp.vec3(float(base[0]), float(base[1]), float(base[2]))


@wp.func
def mls_affine(dt: float, volume: float, stress: wp.mat33, mass: float, C: wp.mat33, grid: GridInfo) -> wp.mat33:
    """MLS-MPM: the stress (Kirchhoff, stored by the last G2P) and APIC affine momentum share one
    matrix; D⁻¹ = 4/dx² for quadratic B-splines."""
    return (-dt * volume * 4.0 * grid.inv_dx * grid.inv_dx) * stress + mass * C


@wp.func
def advected_position(xp: wp.vec3, new_v: wp.vec3, dt: float, grid: GridInfo) -> wp.vec3:
    """x + dt·v (m), kept where the particle's B-spline stencil stays inside the grid."""
    xn = (xp + dt * new_v - grid.origin) * grid.inv_dx
    for d in range(3):
        xn[d] = wp.clamp(xn[d], 1.0, float(grid.dims[d]) - 2.001)
    return grid.origin + xn * grid.dx


@wp.func
def gather_velocity(xp: wp.vec3, grid: GridInfo, grid_velocity: wp.array3d(dtype=wp.vec3)):
    """G2P's gather at a particle at xp: its new velocity (m/s) and APIC affine matrix C (1/s), the
    B-spline-weighted sums over the 27 nodes of its stencil (g2p, p2g_column.g2p_carry, and
    batch_kernels.g2p_batched on its run's grid)."""
    base, fx = stencil_of(xp, grid)
    wx = bspline_weights(fx[0])
    wy = bspline_weights(fx[1])
    wz = bspline_weights(fx[2])
    new_v = wp.vec3(0.0)
    new_C = wp.mat33(0.0)
    for i in range(3):
        for j in range(3):
            for k in range(3):
                w = wx[i] * wy[j] * wz[k]
                dpos = (wp.vec3(float(i), float(j), float(k)) - fx) * grid.dx
                gv = grid_velocity[base[0] + i, base[1] + j, base[2] + k]
                new_v = new_v + w * gv
                new_C = new_C + (4.0 * grid.inv_dx * grid.inv_dx * w) * wp.outer(gv, dpos)
    return new_v, new_C


@wp.kernel
def p2g(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
        stress: wp.array(dtype=wp.mat33), volume: wp.array(dtype=float), mass: wp.array(dtype=float),
        fixed: wp.array(dtype=wp.int32), grid: GridInfo, dt: float, grid_mass: wp.array3d(dtype=float),
        grid_momentum: wp.array3d(dtype=wp.vec3), grid_fixed: wp.array3d(dtype=float)):
    p = wp.tid()
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
                wp.atomic_add(grid_momentum, gi, gj, gk, w * (mv + affine * dpos))
                wp.atomic_add(grid_mass, gi, gj, gk, w * m)
                if is_fixed != 0:
                    wp.atomic_add(grid_fixed, gi, gj, gk, w)


stencil_sums = wp.types.matrix(shape=(27, 4), dtype=float)  # per stencil node: momentum xyz, mass


@wp.func
def add_stencil_sums(acc: stencil_sums, base: wp.vec3i, grid_mass: wp.array3d(dtype=float),
                     grid_momentum: wp.array3d(dtype=wp.vec3)):
    """Add the 27 summed node contributions of one base cell to the grid (one atomic per value)."""
    for i in range(3):
        for j in range(3):
            for k in range(3):
                e = (i * 3 + j) * 3 + k
                if acc[e, 3] > 0.0:
                    wp.atomic_add(grid_momentum, base[0] + i, base[1] + j, base[2] + k,
                                  wp.vec3(acc[e, 0], acc[e, 1], acc[e, 2]))
                    wp.atomic_add(grid_mass, base[0] + i, base[1] + j, base[2] + k, acc[e, 3])


@wp.kernel
def p2g_chunked(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
                stress: wp.array(dtype=wp.mat33), volume: wp.array(dtype=float), mass: wp.array(dtype=float),
                fixed: wp.array(dtype=wp.int32), grid: GridInfo, dt: float, run_start: wp.array(dtype=wp.int32),
                n_runs: wp.array(dtype=wp.int32), index: wp.array(dtype=wp.int32), grid_mass: wp.array3d(dtype=float), grid_momentum: wp.array3d(dtype=wp.vec3),
                grid_fixed: wp.array3d(dtype=float)):
    """P2G of `p2g` for cell-sorted particles: thread t takes the particles index[i],
    run_start[t] ≤ i < run_start[t+1] (one cell's run, from the last sort: sort.cell_runs; `index`
    is the identity after the arrays themselves were sorted, or a fresher cell order) and
    sums the contributions of consecutive particles with the same stencil base in registers,
    adding them to the grid only when the base changes — one set of 27 node atomics per cell
    instead of per particle (8× fewer at 8 particles per cell). Correct for any runs and any
    particle order (particles that left their cell since the sort only cost extra atomics).
    The run count n_runs[0] stays on the device: launch N threads, those past it return."""
    t = wp.tid()
    if t >= n_runs[0]:
        return
    start = run_start[t]
    end = run_start[t + 1]
    acc = stencil_sums()
    current = wp.vec3i(-1, -1, -1)
    for i_run in range(start, end):
        p = index[i_run]
        base, fx = stencil_of(x[p], grid)
        if base[0] != current[0] or base[1] != current[1] or base[2] != current[2]:
            if current[0] >= 0:
                add_stencil_sums(acc, current, grid_mass, grid_momentum)
            acc = stencil_sums()
            current = base
        wx = bspline_weights(fx[0])
        wy = bspline_weights(fx[1])
        wz = bspline_weights(fx[2])
        m = mass[p]
        affine = mls_affine(dt, volume[p], stress[p], m, C[p], grid)
        mv = m * v[p]
        held = fixed[p] != 0
        for i in range(3):
            for j in range(3):
                for k in range(3):
                    w = wx[i] * wy[j] * wz[k]
                    dpos = (wp.vec3(float(i), float(j), float(k)) - fx) * grid.dx
                    mom = w * (mv + affine * dpos)
                    e = (i * 3 + j) * 3 + k
                    acc[e, 0] += mom[0]
                    acc[e, 1] += mom[1]
                    acc[e, 2] += mom[2]
                    acc[e, 3] += w * m
                    if held:
                        wp.atomic_add(grid_fixed, base[0] + i, base[1] + j, base[2] + k, w)
    if current[0] >= 0:
        add_stencil_sums(acc, current, grid_mass, grid_momentum)


@wp.func
def node_velocity(m: float, momentum: wp.vec3, held: float, i: int, j: int, k: int, grid: GridInfo, dt: float,
                  time_s: float, gravity: wp.vec3, wind_acc: wp.array(dtype=wp.vec3), wind_lo: wp.array(dtype=wp.vec3),
                  wind_hi: wp.array(dtype=wp.vec3), wind_timing: wp.array(dtype=wp.vec4), n_wind: int,
                  damping: float, air_drag: float, ground_enabled: int, ground_height: float,
                  friction: float, sticky_walls: int, boundary: int) -> wp.vec3:
    """Velocity (m/s) of grid node (i, j, k) after one substep from its summed mass (kg) and
    momentum (kg·m/s): forces, damping, drag, ground and walls; 0 where empty or held (`held` > 0)."""
    vel = wp.vec3(0.0)
    if m > 0.0 and held <= 0.0:
        vel = momentum / m
        node = grid.origin + wp.vec3(float(i), float(j), float(k)) * grid.dx
        acc = gravity
        for w in range(n_wind):
            timing = wind_timing[w]  # start_s, end_s, gust amplitude, gust frequency (Hz)
            lo = wind_lo[w]
            hi = wind_hi[w]
            inside = node[0] >= lo[0] and node[1] >= lo[1] and node[2] >= lo[2]
            inside = inside and node[0] <= hi[0] and node[1] <= hi[1] and node[2] <= hi[2]
            if inside and time_s >= timing[0] and time_s < timing[1]:
                gust = 1.0 + timing[2] * wp.sin(2.0 * wp.pi * timing[3] * time_s)
                acc = acc + gust * wind_acc[w]
        vel = vel + dt * acc
        vel = vel * wp.exp(-damping * dt)  # viscous damping, exact for dv/dt = −c·v
        vel = vel / (1.0 + air_drag * wp.length(vel) * dt)  # quadratic drag a = −k|v|v, implicit
        # the ground (and, when the ground is on, the domain floor: same friction) stops inflow
        on_ground = node[2] <= ground_height or k < boundary
        if ground_enabled != 0 and on_ground and vel[2] < 0.0:
            vn = -vel[2]  # speed into the ground, removed; Coulomb friction slows the tangential part
            vt = wp.vec3(vel[0], vel[1], 0.0)
            speed_t = wp.length(vt)
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
    return vel


@wp.kernel
def grid_update(grid_mass: wp.array3d(dtype=float), grid_momentum: wp.array3d(dtype=wp.vec3),
                grid_fixed: wp.array3d(dtype=float), grid_velocity: wp.array3d(dtype=wp.vec3),
                grid: GridInfo, box_lo: wp.vec3i, dt: float, time_s: float, gravity: wp.vec3,
                wind_acc: wp.array(dtype=wp.vec3), wind_lo: wp.array(dtype=wp.vec3),
                wind_hi: wp.array(dtype=wp.vec3), wind_timing: wp.array(dtype=wp.vec4), n_wind: int,
                damping: float, air_drag: float, ground_enabled: int, ground_height: float,
                friction: float, sticky_walls: int, boundary: int):
    a, b, c = wp.tid()
    i = a + box_lo[0]
    j = b + box_lo[1]
    k = c + box_lo[2]
    m = grid_mass[i, j, k]
    held = grid_fixed[i, j, k]
    momentum = wp.vec3(0.0)
    if m > 0.0 and held <= 0.0:  # empty and held nodes: no momentum read
        momentum = grid_momentum[i, j, k]
    grid_velocity[i, j, k] = node_velocity(m, momentum, held, i, j, k, grid, dt, time_s, gravity, wind_acc, wind_lo,
                                           wind_hi, wind_timing, n_wind, damping, air_drag, ground_enabled,
                                           ground_height, friction, sticky_walls, boundary)
    grid_mass[i, j, k] = 0.0
    grid_momentum[i, j, k] = wp.vec3(0.0)
    grid_fixed[i, j, k] = 0.0


@wp.kernel
def g2p(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
        F: wp.array(dtype=wp.mat33), mu: wp.array(dtype=float), lam: wp.array(dtype=float),
        yield_stress: wp.array(dtype=float), material: wp.array(dtype=wp.int32), Jp: wp.array(dtype=float),
        fixed: wp.array(dtype=wp.int32), grid: GridInfo, mp: MaterialParams, dt: float,
        grid_velocity: wp.array3d(dtype=wp.vec3), stress: wp.array(dtype=wp.mat33)):
    p = wp.tid()
    if fixed[p] != 0:
        v[p] = wp.vec3(0.0)
        C[p] = wp.mat33(0.0)
        return
    new_v, new_C = gather_velocity(x[p], grid, grid_velocity)
    v[p] = new_v
    C[p] = new_C
    x[p] = advected_position(x[p], new_v, dt, grid)

    Fn = (wp.identity(n=3, dtype=float) + dt * new_C) * F[p]
    Fn, Jp_new, tau = update_material(Fn, new_C, mu[p], lam[p], material[p], yield_stress[p], Jp[p], dt, mp)
    F[p] = Fn
    Jp[p] = Jp_new
    stress[p] = tau


_CAPPED: dict[tuple[str, int], wp.Kernel] = {}


def register_capped(kernel: wp.Kernel, max_registers: int | None) -> wp.Kernel:
    """`kernel`, or the same function compiled with at most `max_registers` registers per CUDA thread
    (no effect on the CPU). Why: more resident warps per SM keep more loads in flight in kernels that
    wait on memory. On sm_90 NVRTC gives `g2p` 72 registers (24 warps per SM in blocks of 256; at 64,
    still without spills, 32 fit): measured on the H100 within the frame-to-frame spread, so opt-in.
    (Capping the chunked P2G, 255 registers, at 128 or 80 spilled its 27-node sums and ran at 0.3–0.65×.)"""
    if max_registers is None:
        return kernel
    key = (kernel.key, int(max_registers))
    if key not in _CAPPED:
        _CAPPED[key] = wp.kernel(kernel.func, enable_backward=False, module="unique",
                                 cuda_max_registers=int(max_registers))
    return _CAPPED[key]


@wp.kernel
def add_velocity_in_region(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
                           fixed: wp.array(dtype=wp.int32), lo: wp.vec3, hi: wp.vec3, dv: wp.vec3):
    """Impulse: v += dv for every moving particle inside the box [lo, hi] (m)."""
    p = wp.tid()
    if fixed[p] != 0:
        return
    q = x[p]
    if q[0] >= lo[0] and q[1] >= lo[1] and q[2] >= lo[2] and q[0] <= hi[0] and q[1] <= hi[1] and q[2] <= hi[2]:
        v[p] = v[p] + dv
