"""The batch on Ray (`pip install pixie-gs[ray]`, `pixie annotate ... --ray ADDRESS`): one model
actor per GPU of the cluster (or per CPU worker when it has none), fed by Ray's ActorPool.

Each actor loads the checkpoint once and runs `annotate_job` (read + prepare + predict + write)
on the files it is given, so every node must see the input and output paths (a shared file
system) and have pixie-gs installed. `--ray local` starts a Ray instance on this machine, whose CPU
actors start with this process's torch thread count so their bytes equal a local run's.
"""
from __future__ import annotations

from typing import Iterator

from ..errors import InputError
from .jobs import Job
from .steps import AnnotateOptions


class AnnotateActor:
    """Holds the model of one worker (loaded once) and annotates the jobs Ray hands it."""

    def __init__(self, opts: AnnotateOptions) -> None:
        from ..annotate import get_model
        from ..devices import resolve_torch_device
        from ..progress import set_quiet

        set_quiet(True)
        self.opts = opts
        get_model(opts.checkpoint, resolve_torch_device(opts.device))

    def run(self, job: Job) -> dict:
        from .runner import annotate_job

        return annotate_job(job, self.opts)


def import_ray():
    """The ray module, or a one-line InputError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise InputError("--ray needs Ray: pip install 'pixie-gs[ray]' (or pip install 'ray>=2.9')") from None
    return ray


def start_ray(address: str, workers: int | None):
    """Connect to the cluster at `address` ('auto': the one this node belongs to), or start a local
    instance with `workers` CPUs for 'local'."""
    ray = import_ray()
    kwargs = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        if address == "local":
            ray.init(num_cpus=workers, **kwargs)
        else:
            ray.init(address=address, **kwargs)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise InputError(f"--ray {address}: cannot start or reach Ray ({str(exc).splitlines()[0]})") from None
    return ray


GPU_ACTOR_JOBS = 4  # assets a GPU actor works on at once (default): their CPU steps overlap its model step


def actor_plan(ray, opts: AnnotateOptions, workers: int | None, n_jobs: int) -> tuple[int, int, dict, AnnotateOptions]:
    """(number of actors, assets each works on at once, their resource request, options they run with).

    With GPUs (and --device not cpu): one actor per GPU, each running `workers` (default 4) assets in
    threads, so reading, preparing and writing overlap the network. Else `workers` (default: the
    cluster's CPUs) actors of 1 CPU, one asset at a time, on cpu."""
    from dataclasses import replace

    resources = ray.cluster_resources()
    gpus = int(resources.get("GPU", 0))
    if gpus > 0 and opts.device != "cpu":
        return (max(1, min(gpus, n_jobs)), workers or GPU_ACTOR_JOBS, {"num_gpus": 1, "num_cpus": 1},
                replace(opts, device="cuda"))
    if opts.device == "cuda":
        raise InputError("--device cuda asked for, but the Ray cluster has no GPU")
    count = workers or int(resources.get("CPU", 1))
    return max(1, min(count, n_jobs)), 1, {"num_cpus": 1}, replace(opts, device="cpu")


def local_torch_threads() -> int:
    """torch's CPU thread count in this process. The U-Net's CPU results depend in their last bits on
    the OpenMP thread count the process started with (OMP_NUM_THREADS; changing it later with
    torch.set_num_threads does not give the same bytes), and Ray starts a 1-CPU actor with
    OMP_NUM_THREADS=1: local actors start with this count instead, so their outputs are
    byte-identical to `pixie annotate` run here."""
    import torch

    return torch.get_num_threads()


def run_ray(jobs: list[Job], opts: AnnotateOptions, address: str, workers: int | None = None) -> Iterator[dict]:
    """Annotate `jobs` on Ray, yielding each asset's summary record as it finishes."""
    ray = start_ray(address, workers)
    try:
        from ray.util import ActorPool

        count, concurrent, resources, actor_opts = actor_plan(ray, opts, workers, len(jobs))
        if address == "local" and actor_opts.device == "cpu":
            resources["runtime_env"] = {"env_vars": {"OMP_NUM_THREADS": str(local_torch_threads())}}
        remote_actor = ray.remote(AnnotateActor).options(max_concurrency=concurrent, **resources)
        actors = [remote_actor.remote(actor_opts) for _ in range(count)]
        slots = [actor for actor in actors for _ in range(concurrent)]  # a threaded actor takes `concurrent` jobs
        yield from ActorPool(slots).map_unordered(lambda actor, job: actor.run.remote(job), jobs)
    finally:
        ray.shutdown()
