"""Training loop: masked loss on occupied voxels, per-epoch validation, best checkpoint, resumable.

Batches are rebuilt on the device every step from the stored Gaussians (fresh augmentation each
time, see batch.py). The learning rate follows a warm-up + cosine schedule over whichever ends
first, the epochs or the wall-clock budget, so a time-budgeted run still anneals properly.
Under `torchrun --nproc_per_node N` the same loop runs data-parallel (distributed.py): each global
batch of `batch_size` objects is split over the N processes, and the optimisation stays the one of
a single process.
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
from ..materials import NUM_CLASSES
from ..progress import progress, stage
from .batch import AugmentConfig, Batch, build_batch
from .checkpoint import FeatureSpec, LoadedModel, load_training_state, save_checkpoint, state_path
from .distill import Distillation, check_teacher_fits, distillation_loss, kept_objects, load_teacher
from .distributed import SINGLE, DistContext, barrier, from_main, global_batch_loss, rank_share, sum_across
from .evaluate import evaluate_store
from .part_balance import part_balance_weights
from .predict import grid_channel_names, object_feature_summary, select_inputs
from .step_batches import default_objects_per_build, step_batches
from .unet import DECODER_PARTS, ENCODER_PARTS, MaterialUNet, ModelConfig, masked_loss


@dataclass
class TrainConfig:
    epochs: int = 30
    batch_size: int = 8  # objects per optimiser step (split over the processes under torchrun)
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100  # optimiser steps of linear warm-up before the cosine decay
    time_budget_s: float | None = None
    class_weight: float = 1.0
    part_balance: float = 0.0  # α of part_balance.part_balance_weights: small parts of an object weigh more (0: off)
    seed: int = 0
    augment: bool = True
    tilt_max_deg: float = AugmentConfig.tilt_max_deg  # augmentation: tilt a share of objects by up to this angle
    tilt_share: float = AugmentConfig.tilt_share      # (degrees; AugmentConfig holds the defaults)
    margin_max: float = AugmentConfig.margin_max      # augmentation: each object's grid margin up to this
    decal_share: float = AugmentConfig.decal_share    # augmentation: share of objects with painted decals
    hue_share: float = AugmentConfig.hue_share        # augmentation: share of objects with hue/saturation shifted
    workers: int = 1
    limit_train: int | None = None
    limit_val: int | None = None
    input_mode: str = "full"
    init_from: str | None = None  # start from this checkpoint's weights (same network config), fresh optimiser
    anchor_weight: float = 0.0  # L2-SP: loss += w · Σ (θ − θ_init)² over the weights (needs init_from)
    freeze: list[str] = field(default_factory=list)  # network parts (unet.ENCODER_PARTS…) kept at init_from's weights
    distill_from: str | None = None  # teacher checkpoint whose outputs the student is held near (distill.py)
    distill_weight: float = 1.0  # loss += w · distillation term (with distill_from)
    distill_skip: list[str] = field(default_factory=list)  # object kinds left out of the distillation term
    teacher_pool: str | None = None  # a dataset of teacher-labelled real splats added to the train split
    teacher_pool_repeat: int = 1  # … each of its objects listed this many times per epoch
    keep_epochs: bool = False  # also write every epoch's weights (epoch_checkpoint_path) to pick among them later
    model: dict = field(default_factory=dict)  # ModelConfig overrides (base_channels, multipliers, …)
    objects_per_build: int | None = None  # grids built per call, several steps' worth (None: by device)
    features: dict = field(default_factory=dict)  # FeatureSpec overrides (resolution, filter_voxels)


def epoch_checkpoint_path(out: str | Path, epoch: int) -> Path:
    """Where `--keep-epochs` writes epoch `epoch`'s weights next to `out` (m.pt → m.epoch03.pt).

    Why: the validation split is generated, and a fine-tune's real-capture readings can drift away while
    its validation score still rises (docs/model_card.md, r44), so every epoch is kept to be scored on real
    data (benchmarks/bench_real_set.py) before one is picked."""
    out = Path(out)
    return out.with_name(f"{out.stem}.epoch{epoch:02d}{out.suffix}")


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
VAL_BATCH_CPU, VAL_BATCH_CUDA = 4, 16  # objects per validation pass (CUDA: fewer calls, each with a fixed cost)


def training_label_ranges(records) -> dict[str, list[float]]:
    """(low, high) of the training labels in log10 E (Pa), ν, log10 ρ (kg/m³): stored in the checkpoint,
    and every prediction is clamped to them (pixie_gs/model/predict.py)."""
    import numpy as np

    from ..materials import denormalize_physical

    phys = np.concatenate([r.physical for r in records])
    lo, hi = phys.min(0), phys.max(0)
    e_lo, nu_lo, r_lo = denormalize_physical(lo)
    e_hi, nu_hi, r_hi = denormalize_physical(hi)

    def pair(a: float, b: float) -> list[float]:
        # widened outwards at the 4th decimal; rounded to the 6th first, so float32 noise on a label already at a
        # 4-decimal edge (a teacher's output clamped to 10.9031, read back as 10.9031000137) keeps that edge
        return [math.floor(round(float(a), 6) * 1e4) / 1e4, math.ceil(round(float(b), 6) * 1e4) / 1e4]

    return {"log10_E_pa": pair(np.log10(e_lo), np.log10(e_hi)), "nu": pair(nu_lo, nu_hi),
            "log10_density_kg_m3": pair(np.log10(r_lo), np.log10(r_hi))}


def load_init_weights(net, init_model, init_config: ModelConfig, config: ModelConfig, path) -> bool:
    """Copy a checkpoint's weights into `net` (fine-tuning). The configs must match, except that `net` may
    add an object-context branch the checkpoint lacks (it starts at zero: same outputs). Returns whether
    it did."""
    grows = init_config.context_width == 0 < config.context_width
    same_width = init_config.context_width == config.context_width
    same_otherwise = {**init_config.to_dict(), "context_width": config.context_width} == config.to_dict()
    if not same_otherwise or not (same_width or grows):
        raise InputError("--init checkpoint has a different network configuration", path)
    result = net.load_state_dict(init_model.state_dict(), strict=not grows)
    if grows and (result.unexpected_keys or any(not k.startswith("context.") for k in result.missing_keys)):
        raise InputError("--init checkpoint's weights do not fit the network", path)
    return grows


def batch_loss(model, batch: Batch, counts: bool, names: list[str], inputs: list[str], class_weight: float,
               use_amp: bool, ctx: DistContext = SINGLE, distill: Distillation | None = None,
               part_balance: float = 0.0):
    """Run the model on this rank's share of a global batch (see step_batches.py): returns (loss to
    back-propagate, the loss value of the whole global batch, its parts).

    `distill` (teacher, which objects take part, weight) adds weight · distillation_loss over the kept
    objects' voxels of the whole global batch (parts["distill"]: its unweighted value); the reported loss
    value stays the label loss. `part_balance` > 0 weighs each voxel by its part's size within its object
    (part_balance.py), so an object's small parts count as much as its large ones."""
    import torch

    x = select_inputs(batch.inputs, names, inputs)
    with torch.autocast("cuda", dtype=torch.bfloat16, enabled=use_amp):
        logits, physical = model(x)
    weight = None
    if part_balance > 0:
        weight = part_balance_weights(batch.target_class, batch.target_physical, batch.occupied, part_balance,
                                      logits.shape[1])
    loss, parts = masked_loss(logits, physical, batch.target_class, batch.target_physical, batch.occupied,
                              class_weight, weight)
    if ctx.enabled:
        loss, value, parts = global_batch_loss(loss, parts, int(batch.occupied.sum()), counts, class_weight, ctx,
                                               str(batch.occupied.device))
    else:
        value = float(loss.detach())
    if distill is not None:
        with torch.no_grad(), torch.autocast("cuda", dtype=torch.bfloat16, enabled=use_amp):
            t_logits, t_physical = distill.teacher(x)
        term, kept = distillation_loss(logits, physical, t_logits, t_physical, batch.occupied, distill.keep)
        # like global_batch_loss: scaled by this rank's share of the kept voxels, so DDP's gradient mean is
        # the gradient of the term over the whole global batch
        mine = kept if counts else 0
        total, whole = sum_across([mine, mine * float(term.detach())], ctx, str(batch.occupied.device))
        loss = loss + distill.weight * term * (ctx.world_size * mine / max(total, 1.0))
        parts = {**parts, "distill": whole / max(total, 1.0)}
    return loss, value, parts


def frozen_part_names(parts: list[str]) -> list[str]:
    """The network's top-level parts that `parts` names ("encoder" is every part of unet.ENCODER_PARTS);
    a one-line InputError for a name that is no part (checked before any data is loaded)."""
    names = [n for part in parts for n in (ENCODER_PARTS if part == "encoder" else (part,))]
    unknown = [n for n in names if n not in ENCODER_PARTS + DECODER_PARTS]
    if unknown:
        raise InputError(f"--freeze: no network part named {', '.join(unknown)} (parts: encoder, "
                         f"{', '.join(ENCODER_PARTS + DECODER_PARTS)})")
    return names


def freeze_parts(net, parts: list[str]) -> int:
    """Stop gradients into the named top-level parts of `net`, so their weights stay as loaded; returns how many
    parameters are left to train. Why: a fine-tune of the decoder alone learns from the features the start
    already reads; tried to learn new kinds without moving the real readings, it did not hold them either
    (docs/model_card.md, "Candidates r66 and r67")."""
    names = set(frozen_part_names(parts))
    for name, p in net.named_parameters():
        if name.split(".")[0] in names:
            p.requires_grad_(False)
    left = sum(p.numel() for p in net.parameters() if p.requires_grad)
    if left == 0:
        raise InputError("--freeze leaves no parameter to train")
    return left


def squared_distance(net, anchor: dict):
    """Σ (θ − θ_anchor)² over `net`'s floating-point parameters (a differentiable 0-d tensor).

    Why: the real-capture readings of every fine-tune so far moved with its distance from the start
    weights (docs/model_card.md, r44); `--anchor-weight` adds this, scaled, to the loss (L2-SP, Li et al.
    2018: weight decay toward the start instead of toward zero), and each epoch logs it as `drift_sq`."""
    import torch

    terms = [((p - anchor[name]) ** 2).sum() for name, p in net.named_parameters() if name in anchor]
    return torch.stack(terms).sum() if terms else torch.zeros(())


def validation_loss(model, store, spec: FeatureSpec, names: list[str], inputs: list[str], class_weight: float,
                    use_amp: bool, ctx: DistContext = SINGLE, batch_size: int = VAL_BATCH_CPU) -> float:
    """The training loss (no augmentation) averaged over every occupied voxel of the val split; each
    rank computes its share of the objects, the sums are added over the ranks."""
    import torch

    ids = list(range(len(store)))[ctx.rank::ctx.world_size]
    chunks = [ids[i:i + batch_size] for i in range(0, len(ids), batch_size)]
    total, voxels = 0.0, 0
    with torch.no_grad():
        for chunk in progress(chunks, "val loss", total=len(chunks), unit="batch"):
            batch = build_batch(store, chunk, spec)
            with torch.autocast("cuda", dtype=torch.bfloat16, enabled=use_amp):
                logits, physical = model(select_inputs(batch.inputs, names, inputs))
            loss, _ = masked_loss(logits, physical, batch.target_class, batch.target_physical, batch.occupied,
                                  class_weight)
            count = int(batch.occupied.sum())
            total += float(loss) * count
            voxels += count
    total, voxels = sum_across([total, voxels], ctx, store.device)
    return total / max(voxels, 1.0)


def train(data_dir: str | Path, out: str | Path, cfg: TrainConfig, device: str = "cpu", resume: bool = False,
          log_path: str | Path | None = None, dist: DistContext = SINGLE) -> dict:
    """Train on `data_dir`'s train split, validate on val, keep the best weights at `out`; returns the meta.

    With `dist` of several processes (their group joined, `device` this rank's), the batches are split
    over the ranks; rank 0 alone validates and writes `out`, its state file and the log."""
    import torch

    from .data import DeviceStore, load_split, split_paths

    if cfg.input_mode not in INPUT_MODES:
        raise InputError(f"unknown input mode '{cfg.input_mode}' (choose from {', '.join(INPUT_MODES)})")
    out = Path(out)
    side = state_path(out)
    state = None
    if resume:
        if not side.exists():
            raise InputError("nothing to resume (no training state next to the checkpoint)", side)
        state = load_training_state(side)
        trained_s = float(state["elapsed_s"])
        if cfg.time_budget_s and trained_s + 1.0 >= cfg.time_budget_s:
            raise InputError(f"--time-budget-s {cfg.time_budget_s:.0f} is already spent: the budget counts the "
                             f"{trained_s:.0f} s trained before this resume; give more to train on", side)
    if cfg.distill_skip:  # before the data load (minutes on a large set): a misspelt kind would be distilled
        index = Path(data_dir) / "train" / "index.json"
        kinds = {e.get("class") for e in json.loads(index.read_text()).get("objects", [])} if index.exists() else set()
        unknown = sorted(set(cfg.distill_skip) - kinds)
        if unknown:
            raise InputError(f"--distill-skip: no training object of kind {', '.join(unknown)}", index)
    if cfg.teacher_pool:  # named before the data load (minutes on a large set)
        split_paths(cfg.teacher_pool, "train")
    teacher = load_teacher(cfg.distill_from, device) if cfg.distill_from else None
    t0 = time.perf_counter()
    torch.manual_seed(cfg.seed)
    stage(f"loading training data from {data_dir}")
    extra = list(state["extra_names"]) if state else None
    train_records, extra = load_split(data_dir, "train", extra, cfg.limit_train, cfg.workers)
    val_records, _ = load_split(data_dir, "val", extra, cfg.limit_val, cfg.workers)
    if cfg.teacher_pool:
        pool, _ = load_split(cfg.teacher_pool, "train", extra, None, cfg.workers)
        train_records = train_records + pool * cfg.teacher_pool_repeat
        stage(f"teacher pool {cfg.teacher_pool}: {len(pool)} objects, each listed {cfg.teacher_pool_repeat} times")
    ranges = training_label_ranges(train_records)
    train_store = DeviceStore(train_records, device)
    val_store = DeviceStore(val_records, device)
    del train_records, val_records
    spec = FeatureSpec(**{**FeatureSpec().to_dict(), **cfg.features, "extra_names": tuple(extra)})
    names = grid_channel_names(extra)
    inputs = list(INPUT_MODES[cfg.input_mode] or names)
    mcfg = ModelConfig(input_channels=inputs, **cfg.model)
    net = MaterialUNet(mcfg).to(device)
    # the start weights (after any growth): each epoch logs the drift from them, --anchor-weight penalises
    # it; on --resume they are rebuilt from --init in a spare network, since the state holds only the
    # current weights
    anchor = None
    if cfg.init_from:
        from .checkpoint import load_checkpoint

        init = load_checkpoint(cfg.init_from, "cpu")
        start = MaterialUNet(mcfg) if state else net
        grown = load_init_weights(start, init.model, init.config, mcfg, cfg.init_from)
        if not state:
            stage(f"starting from the weights of {cfg.init_from}"
                  + ("; the new object-context branch starts at zero (the same outputs)" if grown else ""))
        anchor = {name: p.detach().clone().to(device) for name, p in start.named_parameters()}
    if teacher is not None:
        check_teacher_fits(teacher, inputs, spec)
        stage(f"distilling from {cfg.distill_from} (weight {cfg.distill_weight:g}"
              + (f"; not on {', '.join(cfg.distill_skip)})" if cfg.distill_skip else ")"))
    trainable = freeze_parts(net, cfg.freeze)
    params = [p for p in net.parameters() if p.requires_grad]  # all of them unless --freeze
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    history: list[dict] = []
    start_epoch, step, elapsed_before, best = 0, 0, 0.0, -math.inf
    if state:
        net.load_state_dict(state["model"])
        try:
            opt.load_state_dict(state["optimizer"])
        except ValueError:  # its parameter groups differ in size: another --freeze than the run it continues
            raise InputError("--resume: the training state was written with other --freeze parts than these",
                             side) from None
        start_epoch, step = int(state["epoch"]), int(state["step"])
        elapsed_before, best = float(state["elapsed_s"]), float(state["best_score"])
        history = json.loads(state["history_json"])
        stage(f"resuming after epoch {start_epoch} (step {step}, {elapsed_before:.0f} s trained)")
    gen = torch.Generator().manual_seed(cfg.seed + 7919 * start_epoch)  # shuffling: the same on every rank
    model = net
    if dist.enabled:  # after loading weights: DDP starts every rank from rank 0's
        from torch.nn.parallel import DistributedDataParallel

        model = DistributedDataParallel(net, device_ids=[torch.device(device).index] if use_cuda(device) else None)
    aug = (AugmentConfig(tilt_max_deg=cfg.tilt_max_deg, tilt_share=cfg.tilt_share, margin_max=cfg.margin_max,
                         decal_share=cfg.decal_share, hue_share=cfg.hue_share)
           if cfg.augment else None)
    per_build = cfg.objects_per_build or default_objects_per_build(device, spec.resolution,
                                                                       len(names) + NUM_CLASSES + 3)
    val_batch = VAL_BATCH_CUDA if use_cuda(device) else VAL_BATCH_CPU
    steps_per_epoch = math.ceil(len(train_store) / cfg.batch_size)
    total_steps = steps_per_epoch * cfg.epochs
    if cfg.warmup_steps > total_steps // 4:
        stage(f"note: the learning rate warms up over {cfg.warmup_steps} of the run's {total_steps} steps, so it "
              f"never holds --lr for long (--warmup-steps sets the warm-up)")
    use_amp = use_cuda(device)
    if use_amp:
        torch.backends.cudnn.benchmark = True
    meta = {"train_config": asdict(cfg), "train_objects": len(train_store), "val_objects": len(val_store),
            "data_dir": str(data_dir), "history": history, "label_ranges": ranges, "processes": dist.world_size,
            "objects_per_build": per_build}
    where = f"{dist.world_size} processes ({device} on rank 0)" if dist.enabled else device
    frozen = f" ({', '.join(cfg.freeze)} frozen)" if cfg.freeze else ""
    stage(f"training {trainable} of {sum(p.numel() for p in net.parameters())} parameters{frozen} on {where}: "
          f"{len(train_store)} train / {len(val_store)} val objects, inputs={cfg.input_mode} ({len(inputs)} channels)")
    t_train = time.perf_counter()
    summaries: list = []  # per-object grid statistics of the first batches (out-of-distribution score)
    summarised = 0
    val_seconds = 0.0
    out_of_time = False
    for epoch in range(start_epoch, cfg.epochs):
        model.train()
        order = torch.randperm(len(train_store), generator=gen).tolist()
        batches = [order[i:i + cfg.batch_size] for i in range(0, len(order), cfg.batch_size)]
        sums = {"loss": 0.0, "ce": 0.0, "mse_log_E": 0.0, "mse_nu": 0.0, "mse_log_rho": 0.0}
        if teacher is not None:
            sums["distill"] = 0.0
        done = objects = 0
        t_epoch = time.perf_counter()
        # augmentation: per object and epoch (batch.object_generator), so every rank draws what one process would
        steps = step_batches(train_store, batches, spec, aug, cfg.seed * 7919 + epoch, dist, per_build)
        for ids, batch, counts in progress(steps, f"epoch {epoch + 1}/{cfg.epochs}", total=len(batches),
                                           unit="batch"):
            elapsed = elapsed_before + time.perf_counter() - t_train
            if cfg.time_budget_s:
                stop = elapsed + 1.2 * val_seconds >= cfg.time_budget_s
                elapsed, stop = from_main([elapsed, stop], dist, device)  # rank 0's clock decides for all
                if stop:
                    out_of_time = True
                    break
            for g in opt.param_groups:
                g["lr"] = learning_rate(cfg, step, total_steps, elapsed)
            distill = None
            if teacher is not None:
                share, _ = rank_share(ids, dist)  # the objects of this rank's batch, in its order
                keep = torch.tensor(kept_objects(train_store.class_names, share, cfg.distill_skip),
                                    device=batch.occupied.device)
                distill = Distillation(teacher.model, keep, cfg.distill_weight)
            loss, value, parts = batch_loss(model, batch, counts, names, inputs, cfg.class_weight, use_amp, dist,
                                            distill, cfg.part_balance)
            if cfg.anchor_weight > 0:  # every rank adds the same term: DDP's gradient mean keeps it as is
                loss = loss + cfg.anchor_weight * squared_distance(net, anchor)
            if summarised < FEATURE_STATS_OBJECTS:
                summaries.append(object_feature_summary(batch.inputs, batch.occupied).float().cpu())
                summarised += cfg.batch_size if not dist.enabled else len(batch.means_unit)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, 1.0)
            opt.step()
            step += 1
            done += 1
            objects += len(ids)
            sums["loss"] += value
            for k, v in parts.items():
                sums[k] += v
        if done == 0:
            break
        train_seconds = time.perf_counter() - t_epoch
        if summaries and "feature_stats" not in meta:
            f = torch.cat(summaries).double()
            meta["feature_stats"] = {"channels": names + ["log10_occupied_share"], "objects": int(len(f)),
                                     "mean": [round(float(v), 6) for v in f.mean(0)],
                                     "std": [round(float(v), 6) for v in f.std(0)]}
        tv = time.perf_counter()
        net.eval()
        val_loss = validation_loss(net, val_store, spec, names, inputs, cfg.class_weight, use_amp, dist, val_batch)
        if dist.is_main:  # rank 0 alone validates and writes; the others go on to the next epoch
            summary = evaluate_store(LoadedModel(net, mcfg, spec, {}, ""), val_store, val_batch, per_gaussian=False,
                                     desc="validate")
            val_seconds = time.perf_counter() - tv
            elapsed = elapsed_before + time.perf_counter() - t_train
            row = {"epoch": epoch + 1, "steps": step, "elapsed_s": round(elapsed, 1),
                   "train_s": round(train_seconds, 2), "train_objects_per_s": round(objects / train_seconds, 2),
                   "processes": dist.world_size,
                   **{f"train_{k}": round(v / done, 5) for k, v in sums.items()}, "val_loss": round(val_loss, 5),
                   "val_accuracy": round(summary["voxel"]["accuracy"], 5),
                   "val_mse_avg": round(summary["voxel"]["mse_avg"], 5),
                   **{f"val_mse_{k}": round(summary["voxel"][f"mse_{k}"], 5) for k in ("log_E", "nu", "log_rho")}}
            if anchor is not None:
                with torch.no_grad():
                    row["drift_sq"] = float(f"{float(squared_distance(net, anchor)):.6g}")  # 6 significant digits
            history.append(row)
            stage(f"epoch {epoch + 1}: loss {row['train_loss']:.4f}  val loss {val_loss:.4f}  "
                  f"val acc {row['val_accuracy']:.4f}  val mse {row['val_mse_avg']:.4f}  "
                  f"({objects / train_seconds:.1f} objects/s, {elapsed:.0f} s)"
                  + (f"  drift {row['drift_sq']:.3g}" if "drift_sq" in row else ""))
            meta["history"] = history
            if val_score(summary) > best:
                best = val_score(summary)
                meta.update(best_epoch=epoch + 1, val=summary)
                save_checkpoint(out, net, spec, meta)
            if cfg.keep_epochs:
                save_checkpoint(epoch_checkpoint_path(out, epoch + 1), net, spec, {**meta, "epoch": epoch + 1, "val": summary})
            with atomic_path(side, suffix=".tmp") as tmp:
                torch.save({"model": net.state_dict(), "optimizer": opt.state_dict(), "epoch": epoch + 1, "step": step,
                            "elapsed_s": elapsed, "best_score": best, "history_json": json.dumps(history),
                            "extra_names": list(extra)}, tmp)
            if log_path:
                with atomic_path(log_path, suffix=".tmp") as tmp:
                    Path(tmp).write_text(json.dumps({"meta": meta, "wall_s": time.perf_counter() - t0}, indent=1))
        if out_of_time:
            stage(f"time budget of {cfg.time_budget_s:.0f} s reached")
            break
    barrier(dist)  # rank 0 has written everything before any rank returns
    if not out.exists():
        raise InputError("training stopped before a single epoch finished (raise --time-budget-s)", out)
    return meta


def use_cuda(device: str) -> bool:
    return str(device).startswith("cuda")
