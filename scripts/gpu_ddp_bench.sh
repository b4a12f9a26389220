#!/usr/bin/env bash
# Data-parallel training benchmark (issue 16): generate one dataset in parallel, then train the same
# network for the same epochs with the same global batch (a) on one GPU with plain `pixie train` and
# (b) on NPROC GPUs with `torchrun --nproc_per_node NPROC pixie train` (DDP over nccl), and print
# samples/s of each (epochs 2.. only: epoch 1 carries cuDNN autotuning), the ratio and the validation
# loss / accuracy / MSE of each after every epoch. Then, time permitting, the same pair with
# `--build-objects 1` (grids built one step per call, as before the grouped building) for comparison.
# Sized for the lent 2×H200 box (32 cores, no warp) in ≤ 9 minutes; the same script smoke-tests on a
# CPU (gloo) at tiny size:
#   DEVICE=cpu TRAIN=8 VAL=4 GAUSSIANS=600 EPOCHS=2 BATCH=4 RES=16 WIDTH=4 MULT=1,2 WORKERS=2 OUT=/tmp/o scripts/gpu_ddp_bench.sh
set -u -o pipefail
START=$(date +%s)
OUT=${OUT:?set OUT to the output folder}
mkdir -p "$OUT"
DEVICE=${DEVICE:-cuda}; NPROC=${NPROC:-2}; WORKERS=${WORKERS:-14}
TRAIN=${TRAIN:-1600}; VAL=${VAL:-160}; GAUSSIANS=${GAUSSIANS:-12000}; SEED=${SEED:-3}
EPOCHS=${EPOCHS:-5}; BATCH=${BATCH:-32}     # BATCH: objects per optimiser step, split over the GPUs
RES=${RES:-64}; WIDTH=${WIDTH:-16}; MULT=${MULT:-1,2,4}
DATA=${DATA:-/tmp/pixie_ddp_data}
# NVLink multicast stays off on the lent multi-GPU hosts (KINDS.md): keep these set for every process.
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=${OMP_NUM_THREADS:-4}
LOG=$OUT/log.txt
elapsed() { echo $(( $(date +%s) - START )); }
say() { echo "[$(elapsed) s] $*" | tee -a "$LOG"; }

# what the box lacks (plyfile, trimesh, maybe tqdm) comes from wheels carried in the ignored .whl folder
if ! python3 -c "import plyfile, trimesh, tqdm, scipy" 2>/dev/null; then
  python3 -m pip install -q --no-index --no-deps --target /tmp/pixie_site .whl/*.whl >>"$LOG" 2>&1 \
    || say "installing .whl/*.whl failed"
  export PYTHONPATH=/tmp/pixie_site:${PYTHONPATH:-}
fi
export PYTHONPATH=$PWD:${PYTHONPATH:-}
P="python3 -m pixie_gs.cli.main"
say "host: $(nproc --all) cores; $(python3 -c 'import torch; print("torch", torch.__version__, "GPUs", torch.cuda.device_count(), torch.cuda.is_available() and torch.cuda.get_device_name(0))')"
python3 -c "import plyfile, trimesh, tqdm, scipy, pixie_gs.model.train" >>"$LOG" 2>&1 || { say "missing Python packages (see $LOG)"; exit 1; }
if [ "$DEVICE" = cuda ]; then
  GPUS=$(python3 -c 'import torch; print(torch.cuda.device_count())')
  [ "$GPUS" -ge "$NPROC" ] || { say "need $NPROC GPUs, torch sees $GPUS"; exit 1; }
fi

# 1. dataset, generated in parallel (generation needs no warp)
for split in train val; do
  n=$TRAIN; [ $split = val ] && n=$VAL
  $P generate "$DATA" --count $n --split $split --seed $SEED --workers $(nproc --all) --gaussians $GAUSSIANS -q --force \
    >>"$LOG" 2>&1 || { say "generate $split failed (see $LOG)"; exit 1; }
done
say "generated $TRAIN train + $VAL val objects of $GAUSSIANS Gaussians ($(du -sh "$DATA" | cut -f1))"

# 2. the same training on one GPU and on NPROC GPUs
COMMON=(--device "$DEVICE" --epochs $EPOCHS --batch-size $BATCH --resolution $RES --base-channels $WIDTH
        --multipliers $MULT --seed $SEED --workers $WORKERS -q)
DDP_RUN="python3 -m torch.distributed.run --standalone --nproc_per_node $NPROC -m pixie_gs.cli.main"
run_train() {  # name extra-args launcher...
  local name=$1 extra=$2; shift 2
  local left=$(( 530 - $(elapsed) ))
  [ $left -lt 60 ] && { say "no time left for $name ($left s)"; return 1; }
  say "training $name (time limit $left s)"
  timeout $left "$@" train "$DATA" --out "$OUT/$name.pt" --log-json "$OUT/train_$name.json" "${COMMON[@]}" $extra \
    >>"$LOG" 2>&1 && say "trained $name" || { say "train $name failed (see $LOG)"; return 1; }
}
run_train one "" python3 -m pixie_gs.cli.main
run_train ddp "" $DDP_RUN
if [ "${COMPARE_STEPWISE:-1}" = 1 ] && [ $(( 530 - $(elapsed) )) -gt 200 ]; then
  run_train one_stepwise "--build-objects 1" python3 -m pixie_gs.cli.main
  run_train ddp_stepwise "--build-objects 1" $DDP_RUN
fi

# 3. figures
python3 - "$OUT" "$NPROC" <<'PY' | tee -a "$LOG"
import json, pathlib, sys
out, nproc = pathlib.Path(sys.argv[1]), int(sys.argv[2])
def rate(history, n):  # objects/s over epochs 2.. (all of them when only one epoch ran)
    rows = history[1:] or history
    return n * len(rows) / sum(r["train_s"] for r in rows)
summary = {}
for suffix, what in (("", "grids of several steps per build call"), ("_stepwise", "--build-objects 1")):
    pair = {}
    for base in ("one", "ddp"):
        p = out / f"train_{base}{suffix}.json"
        if not p.exists():
            continue
        doc = json.loads(p.read_text())
        meta, hist = doc["meta"], doc["meta"]["history"]
        label = "1 GPU" if base == "one" else f"{nproc} GPUs (torchrun, DDP)"
        s = pair[base] = {"samples_per_s": round(rate(hist, meta["train_objects"]), 2), "epochs": len(hist),
                          "objects_per_build": meta.get("objects_per_build"), "wall_s": round(doc["wall_s"], 1),
                          "val_loss": [r["val_loss"] for r in hist], "val_accuracy": [r["val_accuracy"] for r in hist],
                          "val_mse_avg": [r["val_mse_avg"] for r in hist], "train_s": [r["train_s"] for r in hist]}
        print(f"[{what}] {label}: {s['samples_per_s']:.1f} samples/s (epochs 2..{len(hist)}), epoch train s "
              f"{s['train_s']}, {s['objects_per_build']} objects per build, wall {s['wall_s']} s")
        print(f"   val loss per epoch {s['val_loss']}  val acc {s['val_accuracy']}  val mse {s['val_mse_avg']}")
    if len(pair) == 2:
        ratio = pair["ddp"]["samples_per_s"] / pair["one"]["samples_per_s"]
        a, b = pair["one"]["val_loss"][-1], pair["ddp"]["val_loss"][-1]
        pair.update(ratio=round(ratio, 3), final_val_loss_relative_difference=round(abs(b - a) / a, 4))
        print(f"[{what}] throughput ratio {nproc} GPUs / 1 GPU: {ratio:.2f}x;  final val loss {a:.4f} vs {b:.4f} "
              f"({100 * abs(b - a) / a:.1f} % apart)")
    if pair:
        summary["grouped" if not suffix else "stepwise"] = pair
(out / "summary.json").write_text(json.dumps(summary, indent=1))
PY
rm -f "$OUT"/*.pt   # checkpoints are not needed back; the logs carry the figures
say "done"
