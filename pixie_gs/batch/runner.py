"""The local batch: the model is loaded once in this process and runs the assets one after another
while a pool (threads or processes) reads + prepares the next ones and turns the finished ones'
voxel grids into materials and writes them: this process only runs the model (field + U-Net), the
part that cannot be spread over cores.

Each step catches its own failure, so a bad file becomes a `failed` summary line with its one-line
error and the other assets still run. `annotate_job` (all three steps in one call) is what a Ray
actor runs per asset.
"""
from __future__ import annotations

import concurrent.futures as cf
import threading
import time
from contextlib import contextmanager
from typing import Iterator

from .jobs import Job
from .steps import AnnotateOptions, PreparedAsset, assemble, predict_grids, read_prepared, write_result
from .summary import asset_record, error_line

POOL_KINDS = ("process", "thread")


class Failed:
    """A step's failure, picklable: the one-line message and the exit code it maps to (1 input, 3 computation)."""

    def __init__(self, exc: BaseException, path: str) -> None:
        from ..errors import PixieError

        self.message = error_line(exc, path)
        self.exit_code = exc.exit_code if isinstance(exc, PixieError) else 3


def load_step(job: Job, opts: AnnotateOptions) -> tuple[PreparedAsset | Failed, float]:
    """Read + prepare one input in a pool worker: (asset or Failed, seconds)."""
    t = time.perf_counter()
    try:
        return read_prepared(job.input, opts), time.perf_counter() - t
    except Exception as exc:  # noqa: BLE001 - any failure of one asset must not stop the batch
        return Failed(exc, job.input), time.perf_counter() - t


def write_step(job: Job, asset: PreparedAsset, parts: list, seconds: dict[str, float]) -> dict:
    """Turn the model's grids into the annotated cloud (nearest-voxel transfer, the output's
    properties) and write it (+ sidecar), in a pool worker; returns the asset's summary record."""
    t = time.perf_counter()
    try:
        out = assemble(asset, parts)
    except Exception as exc:  # noqa: BLE001 - e.g. a NaN prediction: this asset fails, the batch goes on
        seconds["write"] = time.perf_counter() - t
        return _failed_record(job, Failed(exc, job.input), seconds)
    try:
        write_result(out, asset.prepared, job.output)
    except Exception as exc:  # noqa: BLE001
        seconds["write"] = time.perf_counter() - t
        return _failed_record(job, Failed(exc, job.output), seconds)
    seconds["write"] = time.perf_counter() - t
    return asset_record(job, "ok", seconds, out)


def model_step(asset: PreparedAsset, opts: AnnotateOptions, job: Job):
    """Run the model of this process on one prepared asset: (its PartPredictions or Failed, seconds)."""
    t = time.perf_counter()
    try:
        return predict_grids(asset, opts), time.perf_counter() - t
    except Exception as exc:  # noqa: BLE001
        return Failed(exc, job.input), time.perf_counter() - t


def annotate_job(job: Job, opts: AnnotateOptions) -> dict:
    """All steps of one asset in the calling process (a Ray actor's unit of work): its summary record."""
    asset, t_load = load_step(job, opts)
    if isinstance(asset, Failed):
        return _failed_record(job, asset, {"read_prepare": t_load})
    parts, t_model = model_step(asset, opts, job)
    seconds = {"read_prepare": t_load, "model": t_model}
    if isinstance(parts, Failed):
        return _failed_record(job, parts, seconds)
    return write_step(job, asset, parts, seconds)


def _failed_record(job: Job, failed: Failed, seconds: dict[str, float]) -> dict:
    return asset_record(job, "failed", seconds, error=failed.message) | {"exit_code": failed.exit_code}


def _quiet_worker() -> None:
    """Pool process initialiser: no stage lines from the workers (the parent shows one progress bar)."""
    from ..progress import set_quiet

    set_quiet(True)


def _started() -> None:
    """A no-op task: submitting one per worker makes the pool spawn all its processes at once."""


def make_pool(kind: str, workers: int) -> cf.Executor:
    """`workers` threads, or processes started with 'spawn' (never fork a process that holds torch's threads).

    The processes are all spawned here, with one thread per numpy/OpenMP pool (`worker_threads`):
    each works on one asset at a time, and pools sized to every core would spin against each other."""
    if kind == "thread":
        return cf.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="pixie-batch")
    import multiprocessing

    from .worker_env import worker_threads

    with worker_threads(1):  # the environment only while the children are spawned: this process is unchanged
        ex = cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                    initializer=_quiet_worker)
        for _ in range(workers):  # each submit that finds no idle worker spawns one, synchronously
            ex.submit(_started)
    return ex


def run_local(jobs: list[Job], opts: AnnotateOptions, workers: int = 2, pool: str = "process",
              model_threads: int = 1) -> Iterator[dict]:
    """Annotate `jobs`, yielding each asset's summary record as it finishes (order not kept).

    The model is loaded here once (`get_model`) and run by `model_threads` threads of this process
    (1 on a CPU: torch already uses every core); `workers` pool workers read + prepare the next
    assets and write the annotated ones."""
    import torch

    from ..annotate import get_model
    from ..devices import resolve_torch_device

    if pool not in POOL_KINDS:
        raise ValueError(f"pool must be one of {POOL_KINDS}")
    ex = make_pool(pool, workers)  # spawned processes start while the model loads
    model_ex = cf.ThreadPoolExecutor(max_workers=model_threads, thread_name_prefix="pixie-model")
    try:
        device = resolve_torch_device(opts.device)
        get_model(opts.checkpoint, device)
        if device.startswith("cuda"):
            torch.cuda.synchronize(device)  # the weights are in place before other streams read them
        yield from _pipeline(ex, model_ex, jobs, opts, ahead=workers + model_threads,
                             torch_threads=torch.get_num_threads(), device=device)
    finally:
        model_ex.shutdown(wait=True, cancel_futures=True)
        ex.shutdown(wait=True, cancel_futures=True)


def use_torch_threads(count: int) -> None:
    """Make torch use `count` CPU threads in the calling thread. OpenMP keeps the count per thread, and
    the U-Net's CPU results depend on it in the last bits, so a model thread takes the count of the
    thread that would run `pixie annotate IN OUT` (the main one)."""
    import torch

    if torch.get_num_threads() != count:
        torch.set_num_threads(count)


_THREAD = threading.local()


@contextmanager
def own_cuda_stream(device: str) -> Iterator[None]:
    """On CUDA, run the body on this thread's own CUDA stream (made once per thread); elsewhere nothing.

    The GPU field waits for the GPU several times per asset (`nonzero`, copies to the host). On the
    one default stream each wait also waits for the work the other model threads queued; on a
    stream per thread it waits for its own asset only, so one thread's host work (Python, launches,
    copies) overlaps another's kernels."""
    if not device.startswith("cuda"):
        yield
        return
    import torch

    stream = getattr(_THREAD, "stream", None)
    if stream is None:
        stream = _THREAD.stream = torch.cuda.Stream(device=device)
    with torch.cuda.stream(stream):
        yield


def _model_task(asset: PreparedAsset, opts: AnnotateOptions, job: Job, t_load: float, torch_threads: int,
                device: str = "cpu"):
    use_torch_threads(torch_threads)
    with own_cuda_stream(device):  # every result comes back as numpy, so nothing outlives the stream's work
        parts, t_model = model_step(asset, opts, job)
    return parts, asset, {"read_prepare": t_load, "model": t_model}


def _pipeline(ex: cf.Executor, model_ex: cf.Executor, jobs: list[Job], opts: AnnotateOptions,
              ahead: int, torch_threads: int, device: str = "cpu") -> Iterator[dict]:
    """Read/prepare → model → write as futures: at most `ahead` assets read but not yet predicted and
    at most `ahead` results waiting to be written, so memory stays bounded for any library size."""
    todo = iter(jobs)
    loading: dict[cf.Future, Job] = {}
    predicting: dict[cf.Future, Job] = {}
    writing: dict[cf.Future, Job] = {}

    def top_up() -> None:
        while len(loading) + len(predicting) < ahead and len(writing) <= ahead:
            job = next(todo, None)
            if job is None:
                return
            loading[ex.submit(load_step, job, opts)] = job

    top_up()
    while loading or predicting or writing:
        done, _ = cf.wait(list(loading) + list(predicting) + list(writing), return_when=cf.FIRST_COMPLETED)
        for fut in done:
            if fut in loading:
                job = loading.pop(fut)
                asset, t_load = fut.result()
                if isinstance(asset, Failed):
                    yield _failed_record(job, asset, {"read_prepare": t_load})
                else:
                    predicting[model_ex.submit(_model_task, asset, opts, job, t_load, torch_threads, device)] = job
            elif fut in predicting:
                job = predicting.pop(fut)
                parts, asset, seconds = fut.result()
                if isinstance(parts, Failed):
                    yield _failed_record(job, parts, seconds)
                else:
                    writing[ex.submit(write_step, job, asset, parts, seconds)] = job
            else:
                writing.pop(fut)
                yield fut.result()
        top_up()
