"""Training loop: masked loss on occupied voxels, per-epoch validation, best checkpoint, resumable.

Batches are rebuilt on the device every step from the stored Gaussians (fresh augmentation each
time, see batch.py). The learning rate follows a warm-up + cosine schedule over whichever ends
first, the epochs or the wall-clock budget, so a time-budgeted run still anneals properly.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..atomic import atomic_path
from ..errors import InputError
from ..field import INPUT_MODES
from ..progress import progress, stage
from .batch import AugmentConfig, build_batch
from .checkpoint import FeatureSpec, LoadedModel, load_training_state, save_checkpoint, state_path
from .evaluate import evaluate_store
from .predict import grid_channel_names, object_feature_summary, select_inputs
from .unet import MaterialUNet, ModelConfig, masked_loss


@dataclass
class TrainConfig:
    epochs: int = 30
    batch_size: int = 8
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    time_budget_s: float | None = None
    class_weight: float = 1.0
    seed: int = 0
    augment: bool = True
    workers: int = 1
    limit_train: int | None = None
    limit_val: int | None = None
    input_mode: str = "full"
    init_from: str | None = None  # start from this checkpoint's weights (same network config), fresh optimiser
    model: dict = field(default_factory=dict)  # ModelConfig overrides (base_channels, multipliers, …)
    features: dict = field(default_factory=dict)  # FeatureSpec overrides (resolution, filter_voxels)


def learning_rate(cfg: TrainConfig, step: int, total_steps: int, elapsed_s: float) -> float:
    """Warm-up then cosine decay on the larger of step and time progress."""
    frac = step / max(total_steps, 1)
    if cfg.time_budget_s:
        frac = max(frac, elapsed_s / cfg.time_budget_s)
    warm = min(1.0, (step + 1) / max(cfg.warmup_steps, 1))
    return cfg.lr * warm * 0.5 * (1.0 + math.cos(math.pi * min(frac, 1.0)))


def val_score(summary: dict) -> float:
    """Higher is better: voxel material accuracy minus the average normalised MSE."""
    return summary["voxel"]["accuracy"] - summary["voxel"]["mse_avg"]


FEATURE_STATS_OBJECTS = 2000  # training objects whose grid statistics are stored in the checkpoint


def training_label_ranges(records) -> dict[str, list[float]]:
    """(low, high) of the training labels in log10 E (Pa), ν, log10 ρ (kg/m³): stored in the checkpoint,
    and every prediction is clamped to them (pixie_gs/model/predict.py)."""
    import numpy as np

    from ..materials import denormalize_physical

    phys = np.concatenate([r.physical for r in records])
    lo, hi = phys.min(0), phys.max(0)
    e_lo, nu_lo, r_lo = denormalize_physical(lo)
    e_hi, nu_hi, r_hi = denormalize_physical(hi)

    def pair(a: float, b: float) -> list[float]:  # widened outwards at the 4th decimal
        return [math.floor(float(a) * 1e4) / 1e4, math.ceil(float(b) * 1e4) / 1e4]

    return {"log10_E_pa": pair(np.log10(e_lo), np.log10(e_hi)), "nu": pair(nu_lo, nu_hi),
            "log10_density_kg_m3": pair(np.log10(r_lo), np.log10(r_hi))}


def train(data_dir: str | Path, out: str | Path, cfg: TrainConfig, device: str = "cpu", resume: bool = False,
          log_path: str | Path | None = None) -> dict:
    """Train on `data_dir`'s train split, validate on val, keep the best weights at `out`; returns the meta."""
    import torch

    from .data import DeviceStore, load_split

    if cfg.input_mode not in INPUT_MODES:
        raise InputError(f"unknown input mode '{cfg.input_mode}' (choose from {', '.join(INPUT_MODES)})")
    out = Path(out)
    side = state_path(out)
    state = None
    if resume:
        if not side.exists():
            raise InputError("nothing to resume (no training state next to the checkpoint)", side)
        state = load_training_state(side)
    t0 = time.perf_counter()
    torch.manual_seed(cfg.seed)
    stage(f"loading training data from {data_dir}")
    extra = list(state["extra_names"]) if state else None
    train_records, extra = load_split(data_dir, "train", extra, cfg.limit_train, cfg.workers)
    val_records, _ = load_split(data_dir, "val", extra, cfg.limit_val, cfg.workers)
    ranges = training_label_ranges(train_records)
    train_store = DeviceStore(train_records, device)
    val_store = DeviceStore(val_records, device)
    del train_records, val_records
    spec = FeatureSpec(**{**FeatureSpec().to_dict(), **cfg.features, "extra_names": tuple(extra)})
    names = grid_channel_names(extra)
    inputs = list(INPUT_MODES[cfg.input_mode] or names)
    mcfg = ModelConfig(input_channels=inputs, **cfg.model)
    model = MaterialUNet(mcfg).to(device)
    if cfg.init_from and not state:
        from .checkpoint import load_checkpoint

        init = load_checkpoint(cfg.init_from, "cpu")
        if init.config.to_dict() != mcfg.to_dict():
            raise InputError("--init checkpoint has a different network configuration", cfg.init_from)
        model.load_state_dict(init.model.state_dict())
        stage(f"starting from the weights of {cfg.init_from}")
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    history: list[dict] = []
    start_epoch, step, elapsed_before, best = 0, 0, 0.0, -math.inf
    if state:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start_epoch, step = int(state["epoch"]), int(state["step"])
        elapsed_before, best = float(state["elapsed_s"]), float(state["best_score"])
        history = json.loads(state["history_json"])
        stage(f"resuming after epoch {start_epoch} (step {step}, {elapsed_before:.0f} s trained)")
    gen = torch.Generator().manual_seed(cfg.seed + 7919 * start_epoch)
    aug = AugmentConfig() if cfg.augment else None
    steps_per_epoch = math.ceil(len(train_store) / cfg.batch_size)
    total_steps = steps_per_epoch * cfg.epochs
    use_amp = str(device).startswith("cuda")
    if use_amp:
        torch.backends.cudnn.benchmark = True
    meta = {"train_config": asdict(cfg), "train_objects": len(train_store), "val_objects": len(val_store),
            "data_dir": str(data_dir), "history": history, "label_ranges": ranges}
    stage(f"training {sum(p.numel() for p in model.parameters())} parameters on {device}: "
          f"{len(train_store)} train / {len(val_store)} val objects, inputs={cfg.input_mode} ({len(inputs)} channels)")
    t_train = time.perf_counter()
    summaries: list = []  # per-object grid statistics of the first batches (out-of-distribution score)
    val_seconds = 0.0
    out_of_time = False
    for epoch in range(start_epoch, cfg.epochs):
        model.train()
        order = torch.randperm(len(train_store), generator=gen).tolist()
        batches = [order[i:i + cfg.batch_size] for i in range(0, len(order), cfg.batch_size)]
        sums = {"loss": 0.0, "ce": 0.0, "mse_log_E": 0.0, "mse_nu": 0.0, "mse_log_rho": 0.0}
        done = 0
        for ids in progress(batches, f"epoch {epoch + 1}/{cfg.epochs}", total=len(batches), unit="batch"):
            elapsed = elapsed_before + time.perf_counter() - t_train
            if cfg.time_budget_s and elapsed + 1.2 * val_seconds >= cfg.time_budget_s:
                out_of_time = True
                break
            for g in opt.param_groups:
                g["lr"] = learning_rate(cfg, step, total_steps, elapsed)
            batch = build_batch(train_store, ids, spec, aug, gen)
            if len(summaries) * cfg.batch_size < FEATURE_STATS_OBJECTS:
                summaries.append(object_feature_summary(batch.inputs, batch.occupied).float().cpu())
            x = select_inputs(batch.inputs, names, inputs)
            with torch.autocast("cuda", dtype=torch.bfloat16, enabled=use_amp):
                logits, physical = model(x)
            loss, parts = masked_loss(logits, physical, batch.target_class, batch.target_physical, batch.occupied,
                                      cfg.class_weight)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            step += 1
            done += 1
            sums["loss"] += float(loss.detach())
            for k, v in parts.items():
                sums[k] += v
        if done == 0:
            break
        if summaries and "feature_stats" not in meta:
            f = torch.cat(summaries).double()
            meta["feature_stats"] = {"channels": names + ["log10_occupied_share"], "objects": int(len(f)),
                                     "mean": [round(float(v), 6) for v in f.mean(0)],
                                     "std": [round(float(v), 6) for v in f.std(0)]}
        tv = time.perf_counter()
        model.eval()
        summary = evaluate_store(LoadedModel(model, mcfg, spec, {}, ""), val_store, per_gaussian=False,
                                 desc="validate")
        val_seconds = time.perf_counter() - tv
        elapsed = elapsed_before + time.perf_counter() - t_train
        row = {"epoch": epoch + 1, "steps": step, "elapsed_s": round(elapsed, 1),
               **{f"train_{k}": round(v / done, 5) for k, v in sums.items()},
               "val_accuracy": round(summary["voxel"]["accuracy"], 5), "val_mse_avg": round(summary["voxel"]["mse_avg"], 5),
               **{f"val_mse_{k}": round(summary["voxel"][f"mse_{k}"], 5) for k in ("log_E", "nu", "log_rho")}}
        history.append(row)
        stage(f"epoch {epoch + 1}: loss {row['train_loss']:.4f}  val acc {row['val_accuracy']:.4f}  "
              f"val mse {row['val_mse_avg']:.4f}  ({elapsed:.0f} s)")
        meta["history"] = history
        if val_score(summary) > best:
            best = val_score(summary)
            meta.update(best_epoch=epoch + 1, val=summary)
            save_checkpoint(out, model, spec, meta)
        with atomic_path(side, suffix=".tmp") as tmp:
            torch.save({"model": model.state_dict(), "optimizer": opt.state_dict(), "epoch": epoch + 1, "step": step,
                        "elapsed_s": elapsed, "best_score": best, "history_json": json.dumps(history),
                        "extra_names": list(extra)}, tmp)
        if log_path:
            with atomic_path(log_path, suffix=".tmp") as tmp:
                Path(tmp).write_text(json.dumps({"meta": meta, "wall_s": time.perf_counter() - t0}, indent=1))
        if out_of_time:
            stage(f"time budget of {cfg.time_budget_s:.0f} s reached")
            break
    if not out.exists():
        raise InputError("training stopped before a single epoch finished (raise --time-budget-s)", out)
    return meta
