"""Block P2G: a group of LANES threads scatters one run of particles of a 2×2×2-cell block.

Why: the chunked P2G (kernels.p2g_chunked) gives one thread one cell run. Its neighbouring
threads read particles a run apart (uncoalesced), every node still takes one atomic per
touching cell (27 per node), and a particle that drifted out of its cell since the last sort
flushes the thread's 27-node sums. Here the particles are sorted by block of 2×2×2 base cells
(sort.cell_order with shift 1), whose stencils span a 4×4×4-node window. A group of 16 threads
walks one run of the block's particles together (all read the same particle: one broadcast
load), each thread owning one x-column (4 nodes) of the window in registers; at the end of the
run each node of the window is added to the grid once — ~4 atomics per particle instead of
~13.5 (at 8 particles per cell, 64 per block). A particle whose base cell left the block since
the sort is scattered straight to its 27 nodes, spread over the group's threads (27 atomics,
no flush). Correct for any run, order and drift; kernels.p2g is the reference it is tested
against (tests/test_sim_kernels.py).
"""
from __future__ import annotations

import warp as wp

from .kernels import GridInfo, bspline_weights, mls_affine, stencil_of

LANES = 16  # threads per run; thread `lane` owns window nodes (a, lane // 4, lane % 4), a = 0..3
BLOCK_SHIFT = 1  # sort key: base cell >> 1 per axis (blocks of 2×2×2 cells, a 4×4×4-node window)
MAX_GROUPS = 32768  # thread groups launched; each takes runs g, g + groups, ... (grid-stride)


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


@wp.kernel
def p2g_blocks(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), C: wp.array(dtype=wp.mat33),
               stress: wp.array(dtype=wp.mat33), volume: wp.array(dtype=float), mass: wp.array(dtype=float),
               fixed: wp.array(dtype=wp.int32), grid: GridInfo, dt: float, run_start: wp.array(dtype=wp.int32),
               n_runs: wp.array(dtype=wp.int32), index: wp.array(dtype=wp.int32), keys: wp.array(dtype=wp.int32),
               groups: int, grid_mass: wp.array3d(dtype=float), grid_momentum: wp.array3d(dtype=wp.vec3),
               grid_fixed: wp.array3d(dtype=float)):
    """P2G of kernels.p2g for particles sorted by block: group g = tid // LANES takes runs
    r = g, g + groups, ... < n_runs[0] (run r: particles index[i], run_start[r] ≤ i <
    run_start[r+1]; keys[i]: block key of sorted position i at the last sort)."""
    t = wp.tid()
    lane = t % LANES
    r = t // LANES
    nj = (grid.dims[1] + 1) >> 1  # blocks along y and z (sort.key_dims, shift 1)
    nk = (grid.dims[2] + 1) >> 1
    jl = lane // 4  # this thread's window column: nodes (o + (a, jl, kl)), a = 0..3
    kl = lane % 4
    count = n_runs[0]
    while r < count:
        start = run_start[r]
        end = run_start[r + 1]
        key = keys[start]
        o = wp.vec3i((key // (nj * nk)) * 2, ((key // nk) % nj) * 2, (key % nk) * 2)  # window origin node
        acc = wp.mat44(0.0)  # row a: momentum xyz, mass of node (o + (a, jl, kl))
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
                for a in range(4):
                    i = a - si
                    w = pick(wx, i) * wyz
                    if w > 0.0:
                        dpos = (wp.vec3(float(i), float(j), float(k)) - fx) * grid.dx
                        mom = w * (mv + affine * dpos)
                        acc[a, 0] += mom[0]
                        acc[a, 1] += mom[1]
                        acc[a, 2] += mom[2]
                        acc[a, 3] += w * m
                        if held:
                            held_w[a] += w
            else:  # drifted out of the run's block: its 27 nodes straight to the grid
                for q in range(2):
                    e = lane + q * LANES
                    if e < 27:
                        i = e // 9
                        j = (e // 3) % 3
                        k = e % 3
                        w = pick(wx, i) * pick(wy, j) * pick(wz, k)
                        dpos = (wp.vec3(float(i), float(j), float(k)) - fx) * grid.dx
                        wp.atomic_add(grid_momentum, base[0] + i, base[1] + j, base[2] + k, w * (mv + affine * dpos))
                        wp.atomic_add(grid_mass, base[0] + i, base[1] + j, base[2] + k, w * m)
                        if held:
                            wp.atomic_add(grid_fixed, base[0] + i, base[1] + j, base[2] + k, w)
        for a in range(4):
            if acc[a, 3] > 0.0:
                wp.atomic_add(grid_momentum, o[0] + a, o[1] + jl, o[2] + kl, wp.vec3(acc[a, 0], acc[a, 1], acc[a, 2]))
                wp.atomic_add(grid_mass, o[0] + a, o[1] + jl, o[2] + kl, acc[a, 3])
            if held_w[a] > 0.0:
                wp.atomic_add(grid_fixed, o[0] + a, o[1] + jl, o[2] + kl, held_w[a])
        r += groups


def group_count(n_particles: int, n_blocks: int, max_run: int) -> int:
    """Thread groups to launch: no more than the runs there can be (one per occupied block plus
    one per max_run particles of a crowded one), at most MAX_GROUPS."""
    bound = min(n_particles, n_blocks) + n_particles // max_run + 1
    return max(1, min(bound, MAX_GROUPS))
