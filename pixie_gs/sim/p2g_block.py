"""Block P2G: a group of 16 or 32 threads scatters one run of particles of a 2×2×2-cell block.

Why: the chunked P2G (kernels.p2g_chunked) gives one thread one cell run: its 27×4 sums take
255 registers (8 resident warps per SM on sm_90, scripts/sim_kernel_registers.py), neighbouring
threads read particles a run apart, every node still takes one atomic per touching cell (27 per
node), and a particle that drifted out of its cell since the last sort flushes the sums. Here the particles are sorted by block of 2×2×2 base cells
(sort.cell_order with shift 1), whose stencils span a 4×4×4-node window. A group of 16 (or 32)
threads walks one run of the block's particles together (all read the same particle: one
broadcast load), each thread owning 4 (or 2) nodes of the window in registers; at the end of the
run each node of the window is added to the grid once — ~4 atomics per particle instead of
~13.5 (at 8 particles per cell, 64 per block). A particle whose base cell left the block since
the sort is scattered straight to its 27 nodes, spread over the group's threads (27 atomics,
no flush). Each thread computes the weights of its own nodes (zero outside the particle's
stencil): 64 node evaluations per particle instead of 27, the price of needing no shuffles.
Correct for any run, order and drift; kernels.p2g is the reference it is tested against
(tests/test_sim_kernels.py).
"""
from __future__ import annotations

import warp as wp

from .kernels import GridInfo, bspline_weights, mls_affine, stencil_of

LANE_CHOICES = (16, 32)  # threads per run (block_kernel)
BLOCK_SHIFT = 1  # sort key: base cell >> 1 per axis (blocks of 2×2×2 cells, a 4×4×4-node window)
MAX_GROUPS = 32768  # thread groups launched; each takes runs g, g + groups, ... (grid-stride)
BLOCK_DIM = 128  # CUDA threads per block: at 96 registers (16 lanes) 5 blocks of 128 fit an SM (20
# warps) where 2 of 256 do (16); at 64 registers (32 lanes) 32 warps either way; no shared memory used
_KERNELS: dict[int, wp.Kernel] = {}  # lanes → compiled kernel


@wp.func
def pick(w: wp.vec3, i: int) -> float:
    """w[i] for i in 0..2, and 0 for any other i (a node outside the stencil)."""
    r = float(0.0)
    if i == 0:
        r = w[0]
    elif i == 1:
        r = w[1]
    elif i == 2:
        r = w[2]
    return r


def block_kernel(lanes: int) -> wp.Kernel:
    """The block P2G kernel for `lanes` threads per run: 16 (thread l owns the window's x-column
    (·, l // 4, l % 4), 4 nodes) or 32 (half a column each, 2 nodes: half the serial work per
    thread, more threads). Built (and compiled) once per lane count."""
    if lanes not in LANE_CHOICES:
        raise ValueError(f"block P2G lanes must be one of {LANE_CHOICES}, got {lanes}")
    if lanes not in _KERNELS:
        _KERNELS[lanes] = _make_block_kernel(lanes)
    return _KERNELS[lanes]


def _make_block_kernel(lanes: int) -> wp.Kernel:
    npl = 64 // lanes  # window nodes per thread (compile-time: the loops below unroll)
    drift_rounds = (27 + lanes - 1) // lanes  # a drifted particle's 27 nodes over the group

    @wp.kernel(module="unique", enable_backward=False)  # no gradients through the scatter
    def p2g_blocks(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
                   stress: wp.array(dtype=wp.mat33), volume: wp.array(dtype=float), mass: wp.array(dtype=float),
                   fixed: wp.array(dtype=wp.int32), grid: GridInfo, dt: float, run_start: wp.array(dtype=wp.int32),
                   n_runs: wp.array(dtype=wp.int32), index: wp.array(dtype=wp.int32),
                   keys: wp.array(dtype=wp.int32), groups: int, grid_mass: wp.array3d(dtype=float),
                   grid_momentum: wp.array3d(dtype=wp.vec3), grid_fixed: wp.array3d(dtype=float)):
        """P2G of kernels.p2g for particles sorted by block: group g = tid // lanes takes runs
        r = g, g + groups, ... < n_runs[0] (run r: particles index[i], run_start[r] ≤ i <
        run_start[r+1]; keys[i]: block key of sorted position i at the last sort)."""
        t = wp.tid()
        lane = t % lanes
        r = t // lanes
        nj = (grid.dims[1] + 1) >> 1  # blocks along y and z (sort.key_dims, shift 1)
        nk = (grid.dims[2] + 1) >> 1
        jl = (lane % 16) // 4  # this thread's window nodes: o + (a0 + a2, jl, kl), a2 < npl
        kl = lane % 4
        a0 = (lane // 16) * npl
        count = n_runs[0]
        while r < count:
            start = run_start[r]
            end = run_start[r + 1]
            key = keys[start]
            o = wp.vec3i((key // (nj * nk)) * 2, ((key // nk) % nj) * 2, (key % nk) * 2)  # window origin node
            acc = wp.mat44(0.0)  # row a2: momentum xyz, mass of node o + (a0 + a2, jl, kl)
            held_w = wp.vec4(0.0)  # summed weights of fixed particles at those nodes
            for i_run in range(start, end):
                p = index[i_run]
                base, fx = stencil_of(x[p], grid)
                wx = bspline_weights(fx[0])
                wy = bspline_weights(fx[1])
                wz = bspline_weights(fx[2])
                m = mass[p]
                affine = mls_affine(dt, volume[p], stress[p], m, C[p], grid)
                mv = m * v[p]
                held = fixed[p] != 0
                si = base[0] - o[0]
                sj = base[1] - o[1]
                sk = base[2] - o[2]
                if si >= 0 and si <= 1 and sj >= 0 and sj <= 1 and sk >= 0 and sk <= 1:
                    j = jl - sj
                    k = kl - sk
                    wyz = pick(wy, j) * pick(wz, k)
                    if wyz > 0.0:  # this thread's column crosses the particle's stencil
                        # mv + affine·dpos with the column's y, z part summed once: 3 FMAs per node, not 9
                        dy = (float(j) - fx[1]) * grid.dx
                        dz = (float(k) - fx[2]) * grid.dx
                        q = mv + wp.vec3(affine[0, 1] * dy + affine[0, 2] * dz, affine[1, 1] * dy + affine[1, 2] * dz,
                                         affine[2, 1] * dy + affine[2, 2] * dz)
                        col0 = wp.vec3(affine[0, 0], affine[1, 0], affine[2, 0])
                        for a2 in range(npl):
                            i = a0 + a2 - si
                            w = pick(wx, i) * wyz
                            if w > 0.0:
                                mom = w * (q + col0 * ((float(i) - fx[0]) * grid.dx))
                                acc[a2, 0] += mom[0]
                                acc[a2, 1] += mom[1]
                                acc[a2, 2] += mom[2]
                                acc[a2, 3] += w * m
                                if held:
                                    held_w[a2] += w
                else:  # drifted out of the run's block: its 27 nodes straight to the grid
                    for rnd in range(drift_rounds):
                        e = lane + rnd * lanes
                        if e < 27:
                            i = e // 9
                            j = (e // 3) % 3
                            k = e % 3
                            w = pick(wx, i) * pick(wy, j) * pick(wz, k)
                            dpos = (wp.vec3(float(i), float(j), float(k)) - fx) * grid.dx
                            gi = base[0] + i
                            gj = base[1] + j
                            gk = base[2] + k
                            wp.atomic_add(grid_momentum, gi, gj, gk, w * (mv + affine * dpos))
                            wp.atomic_add(grid_mass, gi, gj, gk, w * m)
                            if held:
                                wp.atomic_add(grid_fixed, gi, gj, gk, w)
            for a2 in range(npl):
                gi = o[0] + a0 + a2
                if acc[a2, 3] > 0.0:
                    wp.atomic_add(grid_momentum, gi, o[1] + jl, o[2] + kl, wp.vec3(acc[a2, 0], acc[a2, 1], acc[a2, 2]))
                    wp.atomic_add(grid_mass, gi, o[1] + jl, o[2] + kl, acc[a2, 3])
                if held_w[a2] > 0.0:
                    wp.atomic_add(grid_fixed, gi, o[1] + jl, o[2] + kl, held_w[a2])
            r += groups

    return p2g_blocks


def group_count(n_particles: int, n_blocks: int, max_run: int) -> int:
    """Thread groups to launch: no more than the runs there can be (one per occupied block plus
    one per max_run particles of a crowded one), at most MAX_GROUPS."""
    bound = min(n_particles, n_blocks) + n_particles // max_run + 1
    return max(1, min(bound, MAX_GROUPS))
