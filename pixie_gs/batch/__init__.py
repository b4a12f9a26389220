"""Batch annotation of splat libraries: `pixie annotate DIR|GLOB|MANIFEST OUT_DIR`.

jobs.py lists the inputs and shards them, steps.py holds the per-asset steps (the same ones the
single-file command runs, so outputs are byte-identical), summary.py the JSONL record per asset,
runner.py the local pool and ray_runner.py the same job on Ray (the `[ray]` extra). Nothing here
imports warp, so a batch runs on a GPU box that has only torch, numpy, scipy and plyfile.
"""
