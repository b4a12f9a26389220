"""Spatial sorting of the particle arrays: particles of one grid cell sit next to each other.

Why: P2G scatters into the 27 nodes around each particle and G2P gathers from them. In file
order (a splat file is in no spatial order) neighbouring threads touch unrelated nodes, so
memory traffic and atomic conflicts double; in cell order a warp of threads shares a few cells.
The solver keeps its arrays in cell order and a permutation `order` (slot → file index) so
results still come back in file order. Keys are the linear index of the cell holding the
particle's stencil base, sorted with Warp's radix sort (stable: ties keep their order).
The sort also yields the cell runs: where each run of same-cell particles starts, so the chunked
P2G can give one thread one cell (one set of grid atomics per cell instead of per particle).
"""
from __future__ import annotations

from typing import Any

import warp as wp

from .kernels import GridInfo


@wp.kernel
def cell_keys(x: wp.array(dtype=wp.vec3), grid: GridInfo, keys: wp.array(dtype=wp.int32),
              slots: wp.array(dtype=wp.int32)):
    """keys[p] = linear index of the stencil base cell of particle p (z fastest), slots[p] = p."""
    p = wp.tid()
    xg = (x[p] - grid.origin) * grid.inv_dx
    i = wp.clamp(int(xg[0] - 0.5), 0, grid.dims[0] - 1)
    j = wp.clamp(int(xg[1] - 0.5), 0, grid.dims[1] - 1)
    k = wp.clamp(int(xg[2] - 0.5), 0, grid.dims[2] - 1)
    keys[p] = (i * grid.dims[1] + j) * grid.dims[2] + k
    slots[p] = p


@wp.kernel
def gather(src: wp.array(dtype=Any), perm: wp.array(dtype=wp.int32), dst: wp.array(dtype=Any)):
    """dst[i] = src[perm[i]]."""
    i = wp.tid()
    dst[i] = src[perm[i]]


@wp.kernel
def run_heads(keys: wp.array(dtype=wp.int32), max_run: int, column: int, head: wp.array(dtype=wp.int32)):
    """head[i] = 1 where a run starts: a new cell key (`column` > 0: a new key // column, i.e. a
    new column of cells along z when column = grid.dims[2]), or every max_run-th particle (long
    runs are split so no thread gets a crowded cell alone)."""
    i = wp.tid()
    head[i] = 0
    if i == 0 or i % max_run == 0:
        head[i] = 1
    elif column > 0:
        if keys[i] // column != keys[i - 1] // column:
            head[i] = 1
    elif keys[i] != keys[i - 1]:
        head[i] = 1


@wp.kernel
def scatter_run_starts(head: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32),
                       starts: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32)):
    """starts[slot[i]] = i for every run head i (slot = exclusive prefix sum of head); the last
    thread writes the number of runs to count[0] and closes the list with starts[count] = N."""
    i = wp.tid()
    if head[i] != 0:
        starts[slot[i]] = i
    n = head.shape[0]
    if i == n - 1:
        runs = slot[i] + head[i]
        count[0] = runs
        starts[runs] = n


@wp.kernel
def scatter_run_keys(head: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32), keys: wp.array(dtype=wp.int32),
                     run_keys: wp.array(dtype=wp.int32)):
    """run_keys[slot[i]] = keys[i] for every run head i: the cell key of each run's first particle."""
    i = wp.tid()
    if head[i] != 0:
        run_keys[slot[i]] = keys[i]


@wp.kernel
def chunk_starts(chunk: int, n: int, starts: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32)):
    """starts[t] = t·chunk (runs of `chunk` consecutive particles), closed by N; count[0] = runs."""
    t = wp.tid()
    starts[t] = wp.min(t * chunk, n)
    if t == 0:
        count[0] = (n + chunk - 1) // chunk


for _dtype in (float, wp.int32, wp.vec3, wp.mat33):
    wp.overload(gather, {"src": wp.array(dtype=_dtype), "perm": wp.array(dtype=wp.int32),
                         "dst": wp.array(dtype=_dtype)})


def cell_order(x: wp.array, grid: GridInfo) -> tuple[wp.array, wp.array]:
    """(permutation (N,) int32 that puts the particles at positions `x` in cell order (stable),
    their cell keys in that order (N,) int32)."""
    n = x.shape[0]
    keys = wp.empty(2 * n, dtype=wp.int32, device=x.device)  # the radix sort needs 2N of each
    slots = wp.empty(2 * n, dtype=wp.int32, device=x.device)
    wp.launch(cell_keys, dim=n, device=x.device, inputs=[x, grid, keys, slots])
    dims = grid.dims
    bits = max(1, int(dims[0] * dims[1] * dims[2] - 1).bit_length())
    wp.utils.radix_sort_pairs(keys, slots, n, end_bit=bits)
    return wp.clone(slots[:n]), wp.clone(keys[:n])


MAX_RUN = 64  # particles; a longer same-cell run is split


def cell_runs(sorted_keys: wp.array, starts: wp.array, count: wp.array, max_run: int = MAX_RUN, column: int = 0,
              run_keys: wp.array | None = None) -> None:
    """Write into `starts` (capacity ≥ N+1) where each run of equal keys begins, followed by N,
    and the number of runs into count[0] — all on the device (nothing is read back).
    `column` > 0: runs of equal key // column instead (whole columns of cells along z when
    column = grid.dims[2]); `run_keys` (capacity ≥ N): the key of each run's first particle."""
    n = sorted_keys.shape[0]
    d = sorted_keys.device
    head = wp.empty(n, dtype=wp.int32, device=d)
    slot = wp.empty(n, dtype=wp.int32, device=d)
    wp.launch(run_heads, dim=n, device=d, inputs=[sorted_keys, max_run, column, head])
    wp.utils.array_scan(head, slot, inclusive=False)
    wp.launch(scatter_run_starts, dim=n, device=d, inputs=[head, slot, starts, count])
    if run_keys is not None:
        wp.launch(scatter_run_keys, dim=n, device=d, inputs=[head, slot, sorted_keys, run_keys])


def chunk_runs(n: int, chunk: int, starts: wp.array, count: wp.array) -> None:
    """Runs of `chunk` consecutive particles (for particles in no cell order), as cell_runs."""
    runs = (n + chunk - 1) // chunk
    wp.launch(chunk_starts, dim=runs + 1, device=starts.device, inputs=[chunk, n, starts, count])


def permute_in_place(perm: wp.array, arrays: list[wp.array]) -> None:
    """a ← a[perm] for every array (same length as perm), through one scratch array per array."""
    for a in arrays:
        scratch = wp.empty_like(a)
        wp.launch(gather, dim=a.shape[0], device=a.device, inputs=[a, perm, scratch])
        wp.copy(a, scratch)
