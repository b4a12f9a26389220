"""Pool processes of a batch start with one thread per numpy/OpenMP pool; the parent's environment is unchanged."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from pixie_gs.batch.runner import make_pool
from pixie_gs.batch.worker_env import THREAD_VARS, worker_threads


def thread_report(_: int) -> tuple[dict[str, str | None], int]:
    """(the thread variables, threads of this process after a numpy matrix product large enough to thread)."""
    import numpy as np

    a = np.random.default_rng(0).random((400, 400))
    (a @ a).sum()
    tasks = Path("/proc/self/task")
    return {v: os.environ.get(v) for v in THREAD_VARS}, len(os.listdir(tasks)) if tasks.exists() else -1


def test_process_pool_workers_are_single_threaded_and_parent_env_is_kept(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    ex = make_pool("process", 2)
    try:
        assert os.environ["OMP_NUM_THREADS"] == "7" and "OPENBLAS_NUM_THREADS" not in os.environ
        reports = list(ex.map(thread_report, range(6)))
    finally:
        ex.shutdown(wait=True)
    for env, threads in reports:
        assert env == {v: "1" for v in THREAD_VARS}
        if threads != -1:
            assert threads == 1  # no OpenBLAS/OpenMP helper threads


def test_worker_threads_restores_the_environment_after_an_error(monkeypatch):
    monkeypatch.setenv("MKL_NUM_THREADS", "3")
    monkeypatch.delenv("BLIS_NUM_THREADS", raising=False)
    with pytest.raises(RuntimeError):
        with worker_threads(1):
            assert os.environ["MKL_NUM_THREADS"] == os.environ["BLIS_NUM_THREADS"] == "1"
            raise RuntimeError("stop")
    assert os.environ["MKL_NUM_THREADS"] == "3" and "BLIS_NUM_THREADS" not in os.environ
