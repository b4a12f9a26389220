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
