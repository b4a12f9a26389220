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


def torch_loaded() -> bool:
    import sys

    return "torch" in sys.modules


def test_pool_process_reads_prepares_assembles_and_writes_without_torch(tmp_path):
    """A pool process does all its steps (read, prepare, nearest-voxel transfer, write, summary) without
    importing torch: no second copy of its threads and memory in every worker."""
    from pixie_gs.batch.jobs import Job
    from pixie_gs.batch.runner import load_step, model_step, write_step
    from pixie_gs.batch.steps import AnnotateOptions
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.splat import write_splat

    cloud, _ = build_object(load_class_table()["soda_cans"], 3, 3000)
    write_splat(cloud, tmp_path / "in.ply")
    job, opts = Job(0, str(tmp_path / "in.ply"), str(tmp_path / "out.ply")), AnnotateOptions(device="cpu")
    ex = make_pool("process", 1)
    try:
        asset, t_load = ex.submit(load_step, job, opts).result()
        parts, t_model = model_step(asset, opts, job)  # the model runs here, in the parent
        record = ex.submit(write_step, job, asset, parts, {"read_prepare": t_load, "model": t_model}).result()
        assert record["status"] == "ok" and (tmp_path / "out.ply").exists()
        assert ex.submit(torch_loaded).result() is False
    finally:
        ex.shutdown(wait=True)


def test_blas_threads_caps_this_process_pool_and_restores_it():
    """blas_threads sets the numpy OpenBLAS pool of the running process (already loaded, so the
    environment variables cannot) and restores it, also after an error."""
    import numpy as np

    from pixie_gs.batch.worker_env import blas_thread_counts, blas_threads

    before = blas_thread_counts()
    if not before:
        pytest.skip("no OpenBLAS found in this process (not Linux, or numpy built on another BLAS)")
    with pytest.raises(RuntimeError):
        with blas_threads(1):
            assert blas_thread_counts() == [1] * len(before)
            a = np.random.default_rng(0).random((300, 300))
            assert np.isfinite((a @ a).sum())
            raise RuntimeError("stop")
    assert blas_thread_counts() == before
