"""Column P2G: nine threads per run of cell-sorted particles, each sliding a 3-node window along z.

Why: the chunked P2G (kernels.p2g_chunked) keeps one cell run's 27 node sums in registers (255
registers, 8 resident warps per SM) and adds them to the grid once per cell: 27 node atomics per
cell, every node receiving 27 of them. Here a run is up to `max_run` particles of one column of
cells (same stencil-base x and y; the sort's key has z fastest, so a column's cells lie one after
the other along z in sorted order). Each of nine threads owns one (x, y) column of the 3×3
stencil footprint and keeps only three node sums (12 floats) for the nodes base_z, base_z + 1 and
base_z + 2; when the particles move on to the next cell along z the lowest node can receive
nothing more from this run and is added to the grid then. A node gets one atomic per run whose
column footprint covers it (9 in all across a run of cells) instead of 27, and the kernel's small
register set lets many more warps stay resident. Particles that left the run's column since the
sort, or sit below the window, add their own three nodes directly (still correct, only more
atomics), so the result is the same for any particle order.

The grid here is packed: one vec4 per node (momentum xyz in kg·m/s, mass in kg), so a node's
four sums go out as one 16-byte vector atomic (PTX red.global.add.v4.f32) on sm_90 and newer,
and as four scalar atomics elsewhere (older GPUs, the CPU, or vector_atomics = 0).
`grid_update_packed` is kernels.grid_update for this layout (same node_velocity).
Reference twin: kernels.p2g (tests/test_sim_kernels.py compares them).
"""
from __future__ import annotations

import warp as wp

from .constitutive import MaterialParams, update_material
from .kernels import (GridInfo, advected_position, bspline_weights, gather_velocity, mls_affine, node_velocity,
                      stencil_of)

COLUMN_THREADS = 9  # threads per run: one per (x, y) column of the 3×3×3 stencil

_ADD_VEC4 = """
#if defined(__CUDA_ARCH__) && (__CUDA_ARCH__ >= 900)
    if (vector != 0) {
        wp::vec4* ptr = wp::address(grid, i, j, k);
        asm volatile("{\\n\\t.reg .u64 ga;\\n\\tcvta.to.global.u64 ga, %0;\\n\\t"
                     "red.relaxed.gpu.global.add.v4.f32 [ga], {%1, %2, %3, %4};\\n\\t}"
                     :: "l"(ptr), "f"(value.c[0]), "f"(value.c[1]), "f"(value.c[2]), "f"(value.c[3]) : "memory");
        return;
    }
#endif
    wp::atomic_add(grid, i, j, k, value);
"""


@wp.func_native(_ADD_VEC4)
def add_node(grid: wp.array3d(dtype=wp.vec4), i: int, j: int, k: int, value: wp.vec4, vector: int):
    """grid[i, j, k] += value atomically: one vector atomic on sm_90+ when `vector` != 0, else per component."""
    ...


_CUDA_ARCH = """
#if defined(__CUDA_ARCH__)
    return __CUDA_ARCH__ / 10;
#else
    return 0;
#endif
"""


@wp.func_native(_CUDA_ARCH)
def compiled_arch() -> int:
    """The SM architecture the calling kernel was compiled for (90 for sm_90), 0 on the CPU."""
    ...


@wp.kernel
def probe_arch(out: wp.array(dtype=wp.int32)):
    out[0] = compiled_arch()


def vector_atomics_active(device: str) -> bool:
    """Whether kernels compiled for `device` take the 16-byte vector-atomic path (sm_90 or newer;
    Warp may compile PTX for an older architecture, in which case they do not)."""
    if not str(device).startswith("cuda"):
        return False
    out = wp.zeros(1, dtype=wp.int32, device=device)
    wp.launch(probe_arch, dim=1, device=device, inputs=[out])
    return int(out.numpy()[0]) >= 90


@wp.func
def bspline_weight(fx: float, a: int) -> float:
    """Weight of stencil node base + a (a ∈ {0, 1, 2}) for fx = x/dx − base: bspline_weights(fx)[a]."""
    w = bspline_weights(fx)
    if a == 0:
        return w[0]
    if a == 1:
        return w[1]
    return w[2]


@wp.func
def carried_affine(p: int, held: bool, dt: float, volume: wp.array(dtype=float), stress: wp.array(dtype=wp.mat33),
                   m: float, C: wp.array(dtype=wp.mat33), grid: GridInfo) -> wp.mat33:
    """The P2G affine matrix g2p_carry left in `stress` (held particles, which G2P leaves alone:
    kernels.mls_affine of their stress and C = 0)."""
    if held:
        return mls_affine(dt, volume[p], stress[p], m, C[p], grid)
    return stress[p]


@wp.func
def flush_node(grid_mv: wp.array3d(dtype=wp.vec4), i: int, j: int, k: int, acc: wp.vec4, vector: int):
    """Add one node's summed momentum and mass to the grid, if anything landed there."""
    if acc[3] > 0.0:
        add_node(grid_mv, i, j, k, acc, vector)


def _column_kernel(carry: bool) -> wp.Kernel:
    """p2g_column, or (carry) its twin that reads the affine matrices g2p_carry left."""

    @wp.kernel(module="unique")
    def p2g_column(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
                   stress: wp.array(dtype=wp.mat33), volume: wp.array(dtype=float), mass: wp.array(dtype=float),
                   fixed: wp.array(dtype=wp.int32), grid: GridInfo, dt: float, run_start: wp.array(dtype=wp.int32),
                   n_runs: wp.array(dtype=wp.int32), run_key: wp.array(dtype=wp.int32), index: wp.array(dtype=wp.int32),
                   vector_atomics: int, grid_mv: wp.array3d(dtype=wp.vec4), grid_fixed: wp.array3d(dtype=float)):
        """P2G of kernels.p2g into the packed grid: thread t takes run s = t // 9 (particles index[i],
        run_start[s] ≤ i < run_start[s+1], of the column of cells whose first cell has key run_key[s])
        and the stencil column (a, b) = divmod(t % 9, 3). Launch 9·(max runs) threads; those past
        9·n_runs[0] return. The carry twin (p2g_column_carry) reads each moving particle's affine
        matrix from `stress`, where g2p_carry left it."""
        t = wp.tid()
        s = t // COLUMN_THREADS
        if s >= n_runs[0]:
            return
        col = t - s * COLUMN_THREADS
        a = col // 3
        b = col - a * 3
        ny = grid.dims[1]
        nz = grid.dims[2]
        key = run_key[s]
        ci = key // (ny * nz)
        cj = (key // nz) % ny
        cur = key % nz  # the window holds nodes z = cur, cur + 1, cur + 2 of column (ci + a, cj + b)
        gi = ci + a
        gj = cj + b
        acc0 = wp.vec4(0.0)
        acc1 = wp.vec4(0.0)
        acc2 = wp.vec4(0.0)
        for r in range(run_start[s], run_start[s + 1]):
            p = index[r]
            base, fx = stencil_of(x[p], grid)
            m = mass[p]
            held = fixed[p] != 0
            if wp.static(carry):
                affine = carried_affine(p, held, dt, volume, stress, m, C, grid)
            else:
                affine = mls_affine(dt, volume[p], stress[p], m, C[p], grid)
            pi = base[0] + a
            pj = base[1] + b
            kb = base[2]
            inside = pi == gi and pj == gj and kb >= cur  # else: left the run's column since the sort
            if inside and kb > cur:  # nodes below kb are complete: out, and the window moves up
                shift = kb - cur
                flush_node(grid_mv, gi, gj, cur, acc0, vector_atomics)
                if shift >= 2:
                    flush_node(grid_mv, gi, gj, cur + 1, acc1, vector_atomics)
                if shift >= 3:
                    flush_node(grid_mv, gi, gj, cur + 2, acc2, vector_atomics)
                if shift == 1:
                    acc0 = acc1
                    acc1 = acc2
                    acc2 = wp.vec4(0.0)
                elif shift == 2:
                    acc0 = acc2
                    acc1 = wp.vec4(0.0)
                    acc2 = wp.vec4(0.0)
                else:
                    acc0 = wp.vec4(0.0)
                    acc1 = wp.vec4(0.0)
                    acc2 = wp.vec4(0.0)
                cur = kb
            w_ab = bspline_weight(fx[0], a) * bspline_weight(fx[1], b)
            wz = bspline_weights(fx[2])
            # momentum w·(m v + affine·dpos), dpos = ((a, b, c) − fx)·dx, for c = 0, 1, 2
            q = m * v[p] + affine * (wp.vec3(float(a) - fx[0], float(b) - fx[1], -fx[2]) * grid.dx)
            step = affine * wp.vec3(0.0, 0.0, grid.dx)
            w0 = w_ab * wz[0]
            w1 = w_ab * wz[1]
            w2 = w_ab * wz[2]
            q1 = q + step
            q2 = q1 + step
            n0 = wp.vec4(w0 * q[0], w0 * q[1], w0 * q[2], w0 * m)
            n1 = wp.vec4(w1 * q1[0], w1 * q1[1], w1 * q1[2], w1 * m)
            n2 = wp.vec4(w2 * q2[0], w2 * q2[1], w2 * q2[2], w2 * m)
            if held:
                wp.atomic_add(grid_fixed, pi, pj, kb, w0)
                wp.atomic_add(grid_fixed, pi, pj, kb + 1, w1)
                wp.atomic_add(grid_fixed, pi, pj, kb + 2, w2)
            if inside:
                acc0 = acc0 + n0
                acc1 = acc1 + n1
                acc2 = acc2 + n2
            else:  # out of the column, or below the window: its own nodes, directly
                add_node(grid_mv, pi, pj, kb, n0, vector_atomics)
                add_node(grid_mv, pi, pj, kb + 1, n1, vector_atomics)
                add_node(grid_mv, pi, pj, kb + 2, n2, vector_atomics)
        flush_node(grid_mv, gi, gj, cur, acc0, vector_atomics)
        flush_node(grid_mv, gi, gj, cur + 1, acc1, vector_atomics)
        flush_node(grid_mv, gi, gj, cur + 2, acc2, vector_atomics)

    return p2g_column


p2g_column = _column_kernel(False)
p2g_column_carry = _column_kernel(True)

SLAB_THREADS = 3  # p2g_slab: threads per run, one per x-slab of the stencil

slab_sums = wp.types.matrix(shape=(3, 4), dtype=float)  # per stencil y offset b: momentum xyz, mass


@wp.func
def flush_row(grid_mv: wp.array3d(dtype=wp.vec4), i: int, j: int, k: int, acc: slab_sums, b: int, vector: int):
    """flush_node of row b of a slab window (node (i, j + b, k))."""
    flush_node(grid_mv, i, j + b, k, wp.vec4(acc[b, 0], acc[b, 1], acc[b, 2], acc[b, 3]), vector)


def _slab_kernel(carry: bool) -> wp.Kernel:
    """p2g_slab, or (carry) its twin that reads the affine matrices g2p_carry left."""

    @wp.kernel(module="unique")
    def p2g_slab(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
                 stress: wp.array(dtype=wp.mat33), volume: wp.array(dtype=float), mass: wp.array(dtype=float),
                 fixed: wp.array(dtype=wp.int32), grid: GridInfo, dt: float, run_start: wp.array(dtype=wp.int32),
                 n_runs: wp.array(dtype=wp.int32), run_key: wp.array(dtype=wp.int32), index: wp.array(dtype=wp.int32),
                 vector_atomics: int, grid_mv: wp.array3d(dtype=wp.vec4), grid_fixed: wp.array3d(dtype=float)):
        """p2g_column with three threads per run: thread t takes run t // 3 and the x-slab a = t % 3 of
        the stencil, a 3×3-node window (y offsets b, z nodes cur..cur+2) sliding along z — a third of
        the column kernel's redundant particle reads and weight arithmetic, 36 sums per thread."""
        t = wp.tid()
        s = t // SLAB_THREADS
        if s >= n_runs[0]:
            return
        a = t - s * SLAB_THREADS
        ny = grid.dims[1]
        nz = grid.dims[2]
        key = run_key[s]
        ci = key // (ny * nz)
        cj = (key // nz) % ny
        cur = key % nz
        gi = ci + a
        acc0 = slab_sums()  # z node cur
        acc1 = slab_sums()  # cur + 1
        acc2 = slab_sums()  # cur + 2
        for r in range(run_start[s], run_start[s + 1]):
            p = index[r]
            base, fx = stencil_of(x[p], grid)
            m = mass[p]
            held = fixed[p] != 0
            if wp.static(carry):
                affine = carried_affine(p, held, dt, volume, stress, m, C, grid)
            else:
                affine = mls_affine(dt, volume[p], stress[p], m, C[p], grid)
            wa = bspline_weight(fx[0], a)
            wy = bspline_weights(fx[1])
            wz = bspline_weights(fx[2])
            q = m * v[p] + affine * (wp.vec3(float(a) - fx[0], -fx[1], -fx[2]) * grid.dx)
            step_y = affine * wp.vec3(0.0, grid.dx, 0.0)
            step_z = affine * wp.vec3(0.0, 0.0, grid.dx)
            pi = base[0] + a
            kb = base[2]
            inside = pi == gi and base[1] == cj and kb >= cur
            if inside:
                shift = kb - cur
                if shift >= 1:
                    for b in range(3):
                        flush_row(grid_mv, gi, cj, cur, acc0, b, vector_atomics)
                        if shift >= 2:
                            flush_row(grid_mv, gi, cj, cur + 1, acc1, b, vector_atomics)
                        if shift >= 3:
                            flush_row(grid_mv, gi, cj, cur + 2, acc2, b, vector_atomics)
                    if shift == 1:
                        acc0 = acc1
                        acc1 = acc2
                        acc2 = slab_sums()
                    elif shift == 2:
                        acc0 = acc2
                        acc1 = slab_sums()
                        acc2 = slab_sums()
                    else:
                        acc0 = slab_sums()
                        acc1 = slab_sums()
                        acc2 = slab_sums()
                cur = kb
            for b in range(3):
                qb = q + float(b) * step_y
                for c in range(3):
                    w = wa * wy[b] * wz[c]
                    mom = w * (qb + float(c) * step_z)
                    if held:
                        wp.atomic_add(grid_fixed, pi, base[1] + b, kb + c, w)
                    if inside:
                        if c == 0:
                            acc0[b, 0] += mom[0]
                            acc0[b, 1] += mom[1]
                            acc0[b, 2] += mom[2]
                            acc0[b, 3] += w * m
                        elif c == 1:
                            acc1[b, 0] += mom[0]
                            acc1[b, 1] += mom[1]
                            acc1[b, 2] += mom[2]
                            acc1[b, 3] += w * m
                        else:
                            acc2[b, 0] += mom[0]
                            acc2[b, 1] += mom[1]
                            acc2[b, 2] += mom[2]
                            acc2[b, 3] += w * m
                    else:  # left the run's column since the sort, or below the window: directly
                        add_node(grid_mv, pi, base[1] + b, kb + c, wp.vec4(mom[0], mom[1], mom[2], w * m),
                                 vector_atomics)
        for b in range(3):
            flush_row(grid_mv, gi, cj, cur, acc0, b, vector_atomics)
            flush_row(grid_mv, gi, cj, cur + 1, acc1, b, vector_atomics)
            flush_row(grid_mv, gi, cj, cur + 2, acc2, b, vector_atomics)

    return p2g_slab


p2g_slab = _slab_kernel(False)
p2g_slab_carry = _slab_kernel(True)


def column_threads(n: int, max_run: int, dims: tuple[int, int, int], per_run: int = COLUMN_THREADS) -> int:
    """Threads to launch for p2g_column (per_run 9) or p2g_slab (3): per_run per run, for the most
    runs N particles can form (a run ends at a new column of cells, of which there are
    ≤ dims_x·dims_y, or every max_run-th particle)."""
    return per_run * (-(-n // max_run) + dims[0] * dims[1])


@wp.kernel
def grid_update_packed(grid_mv: wp.array3d(dtype=wp.vec4), grid_fixed: wp.array3d(dtype=float),
                       grid_velocity: wp.array3d(dtype=wp.vec3), grid: GridInfo, box_lo: wp.vec3i, dt: float,
                       time_s: float, gravity: wp.vec3, wind_acc: wp.array(dtype=wp.vec3),
                       wind_lo: wp.array(dtype=wp.vec3), wind_hi: wp.array(dtype=wp.vec3),
                       wind_timing: wp.array(dtype=wp.vec4), n_wind: int, damping: float, air_drag: float,
                       ground_enabled: int, ground_height: float, friction: float, sticky_walls: int, boundary: int):
    """kernels.grid_update for the packed grid (momentum xyz, mass per node); clears it for the next P2G.
    A node nothing landed on (all four sums and the held weight exactly 0) is left as it is: its
    sums are already clear, and its velocity — kept from an earlier substep, finite — is read by no
    G2P with a nonzero weight (a particle's own P2G put mass on every node it reads), so most of a
    mostly-empty domain costs one 16-byte read instead of 32 bytes of writes."""
    a, b, c = wp.tid()
    i = a + box_lo[0]
    j = b + box_lo[1]
    k = c + box_lo[2]
    mv = grid_mv[i, j, k]
    held = grid_fixed[i, j, k]
    if mv[3] == 0.0 and held == 0.0 and mv[0] == 0.0 and mv[1] == 0.0 and mv[2] == 0.0:
        return
    grid_velocity[i, j, k] = node_velocity(mv[3], wp.vec3(mv[0], mv[1], mv[2]), held, i, j, k, grid,
                                           dt, time_s, gravity, wind_acc, wind_lo, wind_hi, wind_timing, n_wind,
                                           damping, air_drag, ground_enabled, ground_height, friction, sticky_walls,
                                           boundary)
    grid_mv[i, j, k] = wp.vec4(0.0)
    grid_fixed[i, j, k] = 0.0


@wp.kernel
def packed_mass(grid_mv: wp.array3d(dtype=wp.vec4), grid_mass: wp.array3d(dtype=float)):
    """The node masses (kg) of the packed grid as their own array (for rigid coupling, sim/rigid.py)."""
    i, j, k = wp.tid()
    grid_mass[i, j, k] = grid_mv[i, j, k][3]


@wp.kernel
def g2p_carry(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
              F: wp.array(dtype=wp.mat33), mu: wp.array(dtype=float), lam: wp.array(dtype=float),
              yield_stress: wp.array(dtype=float), material: wp.array(dtype=wp.int32), Jp: wp.array(dtype=float),
              fixed: wp.array(dtype=wp.int32), grid: GridInfo, mp: MaterialParams, dt: float,
              grid_velocity: wp.array3d(dtype=wp.vec3), stress: wp.array(dtype=wp.mat33),
              volume: wp.array(dtype=float), mass: wp.array(dtype=float)):
    """kernels.g2p for a substep followed by another of the same dt: instead of C and τ it stores
    the next P2G's affine matrix mls_affine(dt, V, τ, m, C) in `stress` (C is not written: 36
    bytes less here, C and V not read by the P2G with carry = 1). Held particles as in g2p."""
    p = wp.tid()
    if fixed[p] != 0:
        v[p] = wp.vec3(0.0)
        C[p] = wp.mat33(0.0)
        return
    new_v, new_C = gather_velocity(x[p], grid, grid_velocity)
    v[p] = new_v
    x[p] = advected_position(x[p], new_v, dt, grid)

    Fn = (wp.identity(n=3, dtype=float) + dt * new_C) * F[p]
    Fn, Jp_new, tau = update_material(Fn, new_C, mu[p], lam[p], material[p], yield_stress[p], Jp[p], dt, mp)
    F[p] = Fn
    Jp[p] = Jp_new
    stress[p] = mls_affine(dt, volume[p], tau, mass[p], new_C, grid)
