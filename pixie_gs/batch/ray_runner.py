"""The batch on Ray (`pip install pixie-gs[ray]`, `pixie annotate ... --ray ADDRESS`): one model
actor per GPU of the cluster (or per CPU worker when it has none), fed by Ray's ActorPool.

Each actor loads the checkpoint once and runs `annotate_job` (read + prepare + predict + write)
on the files it is given, so every node must see the input and output paths (a shared file
system) and have pixie-gs installed. `--ray local` starts a Ray instance on this machine, whose CPU
actors use this process's torch thread count so their bytes equal a local run's.
"""
from __future__ import annotations

from typing import Iterator

from ..errors import InputError
from .jobs import Job
from .steps import AnnotateOptions


class AnnotateActor:
    """Holds the model of one worker (loaded once) and annotates the jobs Ray hands it."""

    def __init__(self, opts: AnnotateOptions, torch_threads: int | None = None) -> None:
        from ..annotate import get_model
        from ..devices import resolve_torch_device
        from ..progress import set_quiet

        set_quiet(True)
        if torch_threads:
            import torch

            torch.set_num_threads(torch_threads)
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


def actor_plan(ray, opts: AnnotateOptions, workers: int | None, n_jobs: int) -> tuple[int, dict, AnnotateOptions]:
    """(number of actors, their resource request, options they run with): one per GPU with 1 GPU each
    when the cluster has GPUs and --device is not cpu; else `workers` (default: the cluster's CPUs)
    with 1 CPU each, on cpu."""
    from dataclasses import replace

    resources = ray.cluster_resources()
    gpus = int(resources.get("GPU", 0))
    if gpus > 0 and opts.device != "cpu":
        return max(1, min(gpus, n_jobs)), {"num_gpus": 1, "num_cpus": 1}, replace(opts, device="cuda")
    if opts.device == "cuda":
        raise InputError("--device cuda asked for, but the Ray cluster has no GPU")
    count = workers or int(resources.get("CPU", 1))
    return max(1, min(count, n_jobs)), {"num_cpus": 1}, replace(opts, device="cpu")


def local_torch_threads() -> int:
    """torch's CPU thread count in this process. The U-Net's CPU results depend on it in the last bits
    (oneDNN splits its reductions by thread), and Ray starts a 1-CPU actor with one thread: local
    actors are given this count so their outputs are byte-identical to `pixie annotate` run here."""
    import torch

    return torch.get_num_threads()


def run_ray(jobs: list[Job], opts: AnnotateOptions, address: str, workers: int | None = None) -> Iterator[dict]:
    """Annotate `jobs` on Ray, yielding each asset's summary record as it finishes."""
    ray = start_ray(address, workers)
    try:
        from ray.util import ActorPool

        count, resources, actor_opts = actor_plan(ray, opts, workers, len(jobs))
        remote_actor = ray.remote(AnnotateActor).options(**resources)
        threads = local_torch_threads() if address == "local" and actor_opts.device == "cpu" else None
        actors = [remote_actor.remote(actor_opts, threads) for _ in range(count)]
        yield from ActorPool(actors).map_unordered(lambda actor, job: actor.run.remote(job), jobs)
    finally:
        ray.shutdown()
