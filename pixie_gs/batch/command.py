"""`pixie annotate DIR|GLOB|MANIFEST OUT_DIR`: list, shard and resume the jobs, run them locally or
on Ray, write the JSONL summary, show progress (rate, ETA), and fail at the end if any asset failed."""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from ..errors import ComputationError, InputError
from .jobs import SPLAT_SUFFIXES, is_finished, list_inputs, make_jobs, parse_shard, select_shard
from .steps import AnnotateOptions
from .summary import SummaryWriter, asset_record, summary_path


def add_batch_options(p: argparse.ArgumentParser) -> None:
    """The options that only batch mode reads."""
    g = p.add_argument_group("batch mode (IN is a folder, a glob or a manifest; OUT is a folder)")
    g.add_argument("--shard", default=None, metavar="i/N",
                   help="annotate only every N-th input starting at i (default: from SLURM_ARRAY_TASK_ID - "
                   "SLURM_ARRAY_TASK_MIN and SLURM_ARRAY_TASK_COUNT when set, else all)")
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="pool workers that read, prepare and write while the model runs (default: 2, or half the "
                   "cores up to 8); with --ray: assets each GPU actor works on at once (default 4), or the "
                   "number of CPU model actors when the cluster has no GPU (default: its CPUs)")
    g.add_argument("--pool", choices=("auto", "process", "thread"), default="auto",
                   help="kind of the local pool (default auto: threads on ≤ 4 cores, where they measured "
                   "faster, processes above)")
    g.add_argument("--model-threads", type=int, default=1, metavar="K",
                   help="threads of this process that run the model (default 1; 2 can help on a GPU, "
                   "where each asset also has CPU work around the network)")
    g.add_argument("--summary", default=None, metavar="FILE.jsonl",
                   help="where the per-asset JSONL goes (default OUT/summary.jsonl, or "
                   "OUT/summary.shard-i-of-N.jsonl for a shard); appended to on resume")
    g.add_argument("--ray", default=None, metavar="ADDRESS",
                   help="run on Ray: a cluster address ('auto' for the one this node is in), or 'local' to start "
                   "one here; one model actor per GPU (needs `pip install pixie-gs[ray]`)")


def run_batch(args: argparse.Namespace) -> int:
    from ..progress import is_quiet, progress, set_quiet

    opts = AnnotateOptions.from_args(args)
    opts.validate()
    if args.rrd:
        raise InputError("--rrd records one splat; it is not available in batch mode")
    for name in ("workers", "model_threads"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise InputError(f"--{name.replace('_', '-')} {value}: need at least 1")
    out_dir = Path(args.output)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("batch mode writes into a folder, but this is a file", out_dir)
    if not out_dir.exists() and out_dir.name.lower().endswith(SPLAT_SUFFIXES):
        raise InputError("batch mode writes into a folder, but this names a splat file "
                         "(give a folder, e.g. annotated/)", out_dir)
    shard = parse_shard(args.shard)
    jobs = select_shard(make_jobs(list_inputs(args.input), out_dir), *shard)
    todo = jobs if args.force else [j for j in jobs if not is_finished(j, not opts.no_prepare)]
    out_dir.mkdir(parents=True, exist_ok=True)
    summary_file = Path(args.summary) if args.summary else summary_path(out_dir, shard)
    quiet = is_quiet()
    shard_note = f" (shard {shard[0]}/{shard[1]})" if shard[1] > 1 else ""
    if not quiet:
        print(f"[pixie] batch: {len(jobs)} asset(s){shard_note}, {len(jobs) - len(todo)} finished before "
              f"(skipped), {len(todo)} to annotate → {out_dir}", file=sys.stderr, flush=True)
    counts = {"ok": 0, "failed": 0, "skipped": 0}
    codes: list[int] = []
    first_error = None
    t0 = time.perf_counter()
    with SummaryWriter(summary_file) as summary:
        todo_ids = {j.index for j in todo}
        for job in jobs:
            if job.index not in todo_ids:
                summary.write(asset_record(job, "skipped"))
                counts["skipped"] += 1
        records = _records(args, opts, todo)
        bar = progress(records, desc="annotate", total=len(todo), unit="asset")
        set_quiet(True)  # the bar (already created) stays; per-asset stage lines would flood it
        try:
            for rec in bar:
                code = rec.pop("exit_code", None)
                summary.write(rec)
                counts[rec["status"]] += 1
                if rec["status"] == "failed":
                    codes.append(code or 1)
                    first_error = first_error or rec.get("error")
                    if not quiet:
                        print(f"[pixie] failed: {rec.get('error')}", file=sys.stderr, flush=True)
        finally:
            set_quiet(quiet)
    seconds = time.perf_counter() - t0
    done = counts["ok"] + counts["failed"]
    rate = f", {done / seconds:.2f} assets/s" if done and seconds > 0 else ""
    print(f"annotated {counts['ok']}, failed {counts['failed']}, skipped {counts['skipped']} (finished before) "
          f"of {len(jobs)}{shard_note} in {seconds:.1f} s{rate}; summary: {summary_file}", flush=True)
    if counts["failed"]:
        error = ComputationError if max(codes) == ComputationError.exit_code else InputError
        raise error(f"{counts['failed']} of {done} asset(s) failed (their summary lines say why; first: "
                    f"{first_error})", summary_file)
    return 0


def default_workers() -> int:
    """Pool workers when --workers is not given: 2, or half the cores on a bigger machine (at most 8)."""
    return min(8, max(2, (os.cpu_count() or 2) // 2))


def _records(args: argparse.Namespace, opts: AnnotateOptions, todo):
    """Summary records of `todo` as they finish, from the local pool or from Ray."""
    if not todo:
        return iter(())
    if args.ray:
        from ..model.checkpoint import load_checkpoint
        from .ray_runner import import_ray, run_ray

        import_ray()
        load_checkpoint(opts.checkpoint, "cpu")  # a bad checkpoint: one error here, not one per actor
        return run_ray(todo, opts, args.ray, args.workers)
    from .runner import run_local

    workers = args.workers or default_workers()
    pool = args.pool if args.pool != "auto" else ("thread" if (os.cpu_count() or 1) <= 4 else "process")
    return run_local(todo, opts, workers=workers, pool=pool, model_threads=args.model_threads)
