"""The JSONL summary of a batch: one line per asset (classes with shares, E quantiles, confidence,
seconds, status and the one-line error of a failed asset), appended as each asset finishes."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..splat import SplatCloud

E_QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)


def asset_record(job, status: str, seconds: dict[str, float] | None = None, out: SplatCloud | None = None,
                 error: str | None = None) -> dict:
    """One summary line. status: ok | failed | skipped; `seconds`: per step (read_prepare, model,
    write) and their sum `total`; `out`: the annotated cloud (materials and confidence summarised)."""
    rec: dict = {"input": job.input, "output": job.output, "status": status}
    if error is not None:
        rec["error"] = error
    if seconds:
        rec["seconds"] = round(sum(seconds.values()), 4)
        rec["step_seconds"] = {k: round(v, 4) for k, v in seconds.items()}
    if out is not None:
        rec.update(material_summary(out))
    return rec


def material_summary(out: SplatCloud) -> dict:
    """Gaussian count, share of each material class (largest first), E quantiles (Pa) and
    confidence (mean, 5th percentile, share under the 'guess' threshold) of an annotated cloud."""
    from ..materials import MATERIAL_NAMES
    from ..model.predict import GUESS_THRESHOLD

    mid, E, _, _ = out.get_materials()
    n = len(mid)
    ids, counts = np.unique(mid, return_counts=True)
    order = np.argsort(-counts, kind="stable")
    classes = {MATERIAL_NAMES.get(int(ids[k]), str(int(ids[k]))): round(float(counts[k]) / n, 5) for k in order}
    rec: dict = {"gaussians": int(n), "classes": classes,
                 "E_pa_quantiles": {f"p{int(q * 100):02d}": float(f"{v:.4g}")
                                    for q, v in zip(E_QUANTILES, np.quantile(E.astype(np.float64), E_QUANTILES))}}
    if out.has("confidence"):
        c = out.get("confidence").astype(np.float64)
        rec["confidence"] = {"mean": round(float(c.mean()), 4), "p05": round(float(np.quantile(c, 0.05)), 4),
                             "share_below_guess": round(float((c < GUESS_THRESHOLD).mean()), 4)}
    return rec


class SummaryWriter:
    """Appends one JSON line per asset to `path` and flushes it, so a killed batch keeps every
    line it finished (a resumed batch appends; `status` tells skipped assets apart)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f = open(self.path, "a", encoding="utf-8")

    def write(self, record: dict) -> None:
        self._f.write(json.dumps(record, ensure_ascii=False) + "\n")
        self._f.flush()

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "SummaryWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def summary_path(out_dir: str | Path, shard: tuple[int, int]) -> Path:
    """OUT_DIR/summary.jsonl, or summary.shard-i-of-N.jsonl for a shard (array tasks never share a file)."""
    i, n = shard
    name = "summary.jsonl" if n == 1 else f"summary.shard-{i}-of-{n}.jsonl"
    return Path(out_dir) / name


def error_line(exc: BaseException, path: str) -> str:
    """The one-line message of a failed asset: a PixieError's own text (it names the file), else
    the file, the exception's type and its first line."""
    from ..errors import PixieError

    if isinstance(exc, PixieError):
        return str(exc)
    text = str(exc).strip().splitlines()
    return f"{path}: {type(exc).__name__}{': ' + text[0] if text else ''}"
