#!/usr/bin/env bash
# Reproduce the shipped checkpoint pixie_gs/data/checkpoints/pixie_default.pt on one GPU box, in one
# command of at most ~10 minutes: generate train/val/test (disjoint seeds via the split salt), train the
# full-feature model with a wall-clock budget, and in parallel the two ablation models (RGB-only and
# occupancy-only inputs, shorter budgets); evaluate all three on the same held-out test split.
# Sizes come from the environment so the same script smoke-tests on a CPU at tiny size:
#   NTRAIN=20 NVAL=6 NTEST=10 GAUSS=3000 DEVICE=cpu TOTAL_S=400 WORKERS=2 OUT=/tmp/o scripts/gpu_train_default.sh
set -u -o pipefail
START=$(date +%s)
OUT=${OUT:?set OUT to the output folder}
NTRAIN=${NTRAIN:-3000}; NVAL=${NVAL:-300}; NTEST=${NTEST:-300}; GAUSS=${GAUSS:-10000}
NABL=${NABL:-1500}                 # train objects used by each ablation model
DEVICE=${DEVICE:-cuda}; WORKERS=${WORKERS:-16}; TOTAL_S=${TOTAL_S:-570}
DATA=${DATA:-/tmp/pixie_data}; SEED=${SEED:-1}
EXTRA_TRAIN_ARGS=${EXTRA_TRAIN_ARGS:-}
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=${OMP_NUM_THREADS:-4}
P="python3 -m pixie_gs.cli.main"
LOG=$OUT/log.txt
elapsed() { echo $(( $(date +%s) - START )); }
say() { echo "[$(elapsed) s] $*" | tee -a "$LOG"; }

say "host: $(nproc) cores; $(python3 -c 'import torch;print(torch.__version__, torch.cuda.is_available() and torch.cuda.get_device_name(0))')"
for split in train val test; do
  n=$NTRAIN; [ $split = val ] && n=$NVAL; [ $split = test ] && n=$NTEST
  $P generate "$DATA" --count $n --split $split --seed $SEED --workers $WORKERS --gaussians $GAUSS -q --force >>"$LOG" 2>&1 \
    || { say "generate $split failed"; exit 1; }
  say "generated $split: $n objects"
done
du -sh "$DATA" >>"$LOG"
NOW=$(elapsed)
FULL_BUDGET=$(( TOTAL_S - NOW - 75 ))            # leave time for loading + test evaluation
ABL_BUDGET=$(( FULL_BUDGET * 45 / 100 ))
[ $FULL_BUDGET -lt 30 ] && { say "no time left to train ($FULL_BUDGET s)"; exit 1; }
say "training: full budget ${FULL_BUDGET} s, ablations ${ABL_BUDGET} s each"
train() {  # name inputs budget extra-args...
  local name=$1 inputs=$2 budget=$3; shift 3
  timeout $(( budget + 90 )) $P train "$DATA" --out "$OUT/$name.pt" --device $DEVICE --epochs 200 \
    --time-budget-s $budget --inputs $inputs --workers $WORKERS --log "$OUT/train_$name.json" -q "$@" $EXTRA_TRAIN_ARGS \
    >>"$LOG" 2>&1 && say "trained $name" || say "train $name failed"
  timeout 120 $P evaluate "$OUT/$name.pt" "$DATA" --split test --device $DEVICE --workers $WORKERS -q \
    --json "$OUT/eval_$name.json" >"$OUT/eval_$name.txt" 2>&1 && say "evaluated $name" || say "evaluate $name failed"
  cat "$OUT/eval_$name.txt" >>"$LOG"
}
train pixie_default full $FULL_BUDGET &
sleep 5
train ablation_rgb rgb $ABL_BUDGET --limit-train $NABL &
train ablation_occupancy occupancy $ABL_BUDGET --limit-train $NABL &
wait
rm -f "$OUT/ablation_rgb.pt" "$OUT/ablation_occupancy.pt" "$OUT"/ablation_*.state.pt "$OUT"/eval_*.txt
python3 - "$OUT" <<'PY'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
logs = {p.stem[len("train_"):]: json.loads(p.read_text()) for p in sorted(out.glob("train_*.json"))}
(out / "train_logs.json").write_text(json.dumps(logs, indent=1))
for p in out.glob("train_*.json"):
    if p.name != "train_logs.json":
        p.unlink()
PY
say "done"
ls -la "$OUT" >>"$LOG"
