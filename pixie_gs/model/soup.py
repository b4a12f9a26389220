"""A "model soup": one checkpoint whose weights are the mean of several checkpoints of the same network.

Why: checkpoints of one training lineage (a run and its fine-tuned continuation, or snapshots along a
run) lie in one basin of the loss, and averaging their weights (Wortsman et al. 2022, "Model soups")
tends to give a model that is more robust to inputs unlike the training data than any one of them, at
no cost at inference. pixie-gs uses it to combine the snapshots of its retraining runs (docs/model_card.md).

    python -m pixie_gs.model.soup OUT.pt IN1.pt IN2.pt [IN3.pt …] [--stats-from K]

The inputs must share the network config, the feature spec and the normalisation ranges (else an
InputError names the first difference). The soup's meta records every input (file name, SHA-256, best
epoch, validation figures; for an input that is itself a soup, its own ingredients), the union of their
label ranges (every prediction is clamped to them) and the grid statistics (out-of-distribution score) of
input K (default: the last one, the newest training data).
"""
from __future__ import annotations

import argparse
import hashlib
from pathlib import Path

from ..atomic import atomic_path
from ..errors import InputError
from .checkpoint import read_payload, validate_payload

MATCHING_KEYS = ("format", "format_version", "features", "normalization")  # and the config, as ModelConfig reads it


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def union_ranges(ranges: list[dict]) -> dict:
    """Per quantity, the lowest low and the highest high of several `label_ranges` dicts."""
    keys = set.intersection(*(set(r) for r in ranges)) if ranges else set()
    return {k: [min(r[k][0] for r in ranges), max(r[k][1] for r in ranges)] for k in sorted(keys)}


def _validation(meta: dict) -> dict | None:
    """A trained checkpoint's voxel validation figures {accuracy, mse_avg}; None for one without (a soup)."""
    return {k: meta["val"]["voxel"][k] for k in ("accuracy", "mse_avg")} if "val" in meta else None


def _ingredient(path: Path, meta: dict) -> dict:
    """One input's record in `soup_of`: its file, hash, best epoch and validation, and, when it is itself
    a soup (no validation of its own), its ingredients' records."""
    record = {"file": path.name, "sha256": _sha256(path), "best_epoch": meta.get("best_epoch"),
              "val_voxel": _validation(meta)}
    if "soup_of" in meta:
        record["soup_of"] = meta["soup_of"]
    return record


def ingredient_validations(meta: dict) -> list[dict]:
    """The validation figures ({accuracy, mse_avg}) of every trained checkpoint a checkpoint is made of:
    its own for a trained one, those of the leaves of a soup (soups of soups included)."""
    if "soup_of" not in meta:
        own = _validation(meta)
        return [] if own is None else [own]
    found = []
    for record in meta["soup_of"]:
        if record.get("val_voxel") is not None:
            found.append(record["val_voxel"])
        elif "soup_of" in record:
            found += ingredient_validations(record)
    return found


def make_soup(inputs: list[str | Path], out: str | Path, stats_from: int = -1) -> dict:
    """Average the weights of `inputs` into `out` (written atomically); returns the soup's meta."""
    import torch

    if len(inputs) < 2:
        raise InputError("a soup needs at least two checkpoints")
    paths = [Path(p) for p in inputs]
    payloads, configs = [], []
    for p in paths:  # each one a valid checkpoint (schema, sizes, finite weights) before any averaging
        payload = read_payload(p)
        configs.append(validate_payload(payload, p)[0].to_dict())  # with defaults for keys older files lack
        payloads.append(payload)
    first = payloads[0]
    for p, payload, config in zip(paths[1:], payloads[1:], configs[1:]):
        if config != configs[0]:
            raise InputError(f"'config' differs from {paths[0].name}'s: not the same network", p)
        for key in MATCHING_KEYS:
            if payload.get(key) != first.get(key):
                raise InputError(f"'{key}' differs from {paths[0].name}'s: not the same network", p)
        if set(payload["state_dict"]) != set(first["state_dict"]):
            raise InputError(f"its weights have other names than {paths[0].name}'s", p)
    state = {}
    for name, tensor in first["state_dict"].items():
        if tensor.is_floating_point():
            total = sum(pl["state_dict"][name].double() for pl in payloads)
            state[name] = (total / len(payloads)).to(tensor.dtype)
        else:  # integer buffers (none in MaterialUNet today) must agree
            if any(not torch.equal(pl["state_dict"][name], tensor) for pl in payloads[1:]):
                raise InputError(f"integer buffer '{name}' differs between the checkpoints")
            state[name] = tensor
    metas = [pl.get("meta", {}) for pl in payloads]
    meta = {
        "soup_of": [_ingredient(p, m) for p, m in zip(paths, metas)],
        "feature_stats_from": paths[stats_from].name,
    }
    ranges = [m["label_ranges"] for m in metas if "label_ranges" in m]
    if ranges:
        meta["label_ranges"] = union_ranges(ranges)
    if "feature_stats" in metas[stats_from]:
        meta["feature_stats"] = metas[stats_from]["feature_stats"]
    payload = {**{k: first[k] for k in MATCHING_KEYS if k in first}, "config": configs[0], "state_dict": state, "meta": meta}
    with atomic_path(out, suffix=".pt.tmp") as tmp:
        torch.save(payload, tmp)
    return meta


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="checkpoint to write (.pt)")
    ap.add_argument("inputs", nargs="+", help="checkpoints of the same network")
    ap.add_argument("--stats-from", type=int, default=-1, metavar="K",
                    help="index of the input whose grid statistics the soup keeps (default: the last)")
    args = ap.parse_args(argv)
    meta = make_soup(args.inputs, args.out, args.stats_from)
    print(f"{args.out}: mean of {len(meta['soup_of'])} checkpoints "
          f"({', '.join(s['file'] for s in meta['soup_of'])}); grid statistics from {meta['feature_stats_from']}")


if __name__ == "__main__":
    main()
