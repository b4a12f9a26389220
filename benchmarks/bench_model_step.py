"""Benchmark: how many assets/s the model process of a batch can sustain on its own (the part a pool
cannot spread over cores), with 1, 2, … model threads, and where one asset's model step spends its time.

Generates `--count` assets (as bench_batch_annotate.py), reads and prepares them once in a process
pool, then in this process: one warm-up, the stages of one asset's model step with the device
synchronised (feature field incl. its host work and copies, then the rest: U-Net, confidence, copies
back), and the model step alone over all assets with each `--threads` count (each model thread on its
own CUDA stream, as `pixie annotate DIR OUT` runs it). The baseline is 1 thread in the same run.

    python benchmarks/bench_model_step.py --count 24 --device cuda --threads 1,2,3
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def stage_seconds(assets: list, opts, device: str) -> dict[str, float]:
    """Mean seconds per asset of the field (`feature_grid`, host work included) and of the whole model
    step (`predict_grids`), the device synchronised after each."""
    import numpy as np
    import torch

    from pixie_gs.annotate import get_model
    from pixie_gs.batch.steps import predict_grids
    from pixie_gs.field import feature_grid

    sync = (lambda: torch.cuda.synchronize(device)) if device.startswith("cuda") else (lambda: None)
    spec = get_model(opts.checkpoint, device).features
    field = total = 0.0
    for asset in assets:
        object_id = asset.model_cloud.get("object_id")
        sync()
        t = time.perf_counter()
        for obj in asset.prepared.objects:
            part = asset.model_cloud.subset(np.nonzero(object_id == obj.object_id)[0])
            feature_grid(part, spec.resolution, list(spec.extra_names), device=device, filter_voxels=spec.filter_voxels,
                         margin=spec.margin, up=asset.prepared.up_vector,
                         box=(np.asarray(obj.fit_box_up[0]), np.asarray(obj.fit_box_up[1])))
        sync()
        field += time.perf_counter() - t
        t = time.perf_counter()
        predict_grids(asset, opts)
        sync()
        total += time.perf_counter() - t
    return {"field": field / len(assets), "model_step": total / len(assets)}


def threaded_rate(assets: list, opts, device: str, threads: int) -> tuple[float, float]:
    """(assets/s, process CPU-s per asset) of the model step alone over `assets` with `threads` threads."""
    from pixie_gs.batch.jobs import Job
    from pixie_gs.batch.runner import model_step, own_cuda_stream

    def one(i: int):
        with own_cuda_stream(device):
            out, _ = model_step(assets[i], opts, Job(i, "", ""))
        if not isinstance(out, list):
            raise SystemExit(f"model step failed: {out.message}")

    c, t = time.process_time(), time.perf_counter()
    with cf.ThreadPoolExecutor(threads) as ex:
        list(ex.map(one, range(len(assets))))
    wall = time.perf_counter() - t
    return len(assets) / wall, (time.process_time() - c) / len(assets)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=24, help="assets (default 24)")
    ap.add_argument("--gaussians", type=int, default=100_000, help="Gaussians per asset (default 100k)")
    ap.add_argument("--device", default="cpu", help="cpu | cuda (default cpu)")
    ap.add_argument("--threads", default="1,2,3", help="model thread counts to time (default 1,2,3)")
    ap.add_argument("--dir", default=None, help="folder of assets to reuse or create (default: temporary)")
    args = ap.parse_args()

    import torch

    from bench_batch_annotate import generate
    from pixie_gs.annotate import get_model
    from pixie_gs.batch.jobs import Job
    from pixie_gs.batch.runner import load_step, make_pool
    from pixie_gs.batch.steps import AnnotateOptions
    from pixie_gs.devices import resolve_torch_device
    from pixie_gs.progress import set_quiet

    set_quiet(True)
    device = resolve_torch_device(args.device)
    lib = Path(args.dir or tempfile.mkdtemp(prefix="pixie-bench-model-"))
    lib.mkdir(parents=True, exist_ok=True)
    files = sorted(lib.glob("asset_*.ply"))
    if len(files) < args.count:
        generate(lib, args.count, args.gaussians, os.cpu_count() or 1)
        files = sorted(lib.glob("asset_*.ply"))
    files = files[: args.count]
    opts = AnnotateOptions(device=device)
    t = time.perf_counter()
    pool = make_pool("process", max(1, min(len(files), (os.cpu_count() or 2) - 1)))
    loaded = list(pool.map(load_step, [Job(i, str(f), "") for i, f in enumerate(files)], [opts] * len(files)))
    pool.shutdown()
    assets = [a for a, _ in loaded]
    print(f"{device} (torch {torch.__version__}), {os.cpu_count()} cores, torch threads {torch.get_num_threads()}; "
          f"{len(assets)} assets read + prepared in {time.perf_counter() - t:.1f} s "
          f"({sum(len(a.cloud) for a in assets) / len(assets):.0f} Gaussians each)", flush=True)
    get_model(None, device)
    threaded_rate(assets[:2], opts, device, 1)  # warm-up: kernels, allocator, cuDNN choices
    st = stage_seconds(assets[: min(8, len(assets))], opts, device)
    print(f"one asset, synchronised: field {1000 * st['field']:.1f} ms (host prep + copies included), whole model "
          f"step {1000 * st['model_step']:.1f} ms, so U-Net + rest {1000 * (st['model_step'] - st['field']):.1f} ms",
          flush=True)
    base = None
    for k in (int(x) for x in args.threads.split(",")):
        rate, cpu = threaded_rate(assets, opts, device, k)
        base = base or (k, rate)
        print(f"model step alone, {k} thread(s): {rate:.2f} assets/s ({rate / base[1]:.2f}× {base[0]} thread(s)), "
              f"{cpu:.3f} CPU-s per asset in this process (load average {os.getloadavg()[0]:.1f})", flush=True)


if __name__ == "__main__":
    main()
