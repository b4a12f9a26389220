"""Thread caps for the spawned pool workers of a batch.

Each pool worker reads, prepares and writes one asset at a time on one core. Left alone, its numpy
(OpenBLAS/MKL) and OpenMP pools size themselves to every core of the machine: 12 workers on a
16-core box hold ~200 threads that spin between small matrix calls and burn CPU time the other
workers need. Those pools read their size from the environment once, when the library loads, which
in a spawned worker happens before any initializer runs (the child re-imports the parent's main
module first). So the caps go into the environment the workers are spawned with.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Iterator

# Environment variables that size the thread pools of OpenMP, OpenBLAS, MKL, BLIS, Accelerate, numexpr.
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


@contextmanager
def worker_threads(count: int = 1) -> Iterator[None]:
    """While inside, processes started by this one get `count` threads per pool (THREAD_VARS);
    the previous environment is restored after. Libraries this process already loaded keep their
    own sizes (they read the variables at load time), so the caller's model threads are unchanged."""
    saved = {name: os.environ.get(name) for name in THREAD_VARS}
    os.environ.update({name: str(count) for name in THREAD_VARS})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


# set/get entry points of the OpenBLAS builds numpy and scipy wheels ship (symbol-prefixed, 64-bit ints)
_OPENBLAS_SET = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                 "openblas_set_num_threads64_", "openblas_set_num_threads")
_OPENBLAS_GET = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                 "openblas_get_num_threads64_", "openblas_get_num_threads")


def _loaded_openblas() -> list[tuple[object, object]]:
    """(set, get) functions of every OpenBLAS this process has loaded (Linux: /proc/self/maps;
    elsewhere none are found and the caps below do nothing)."""
    import ctypes

    try:
        with open("/proc/self/maps") as f:
            paths = sorted({line.split()[-1] for line in f if "openblas" in line.lower() and "/" in line})
    except OSError:
        return []
    found = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _OPENBLAS_SET if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _OPENBLAS_GET if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            setter.argtypes, getter.restype = [ctypes.c_int], ctypes.c_int
            found.append((setter, getter))
    return found


def blas_thread_counts() -> list[int]:
    """Threads of each loaded OpenBLAS pool (empty when none is found)."""
    return [int(get()) for _, get in _loaded_openblas()]


@contextmanager
def blas_threads(count: int = 1) -> Iterator[None]:
    """While inside, the OpenBLAS pools THIS process already loaded (numpy's) use `count` threads;
    the previous counts are restored after. For a process whose matrix work is small and
    sequential (diagnose's least squares on a few columns): an idle pool sized to every core
    spins after each call (36 CPU-s in a 7-s diagnosis on a 16-core host) for no speed-up."""
    libs = _loaded_openblas()
    before = [int(get()) for _, get in libs]
    for setter, _ in libs:
        setter(count)
    try:
        yield
    finally:
        for (setter, _), n in zip(libs, before):
            setter(n)
