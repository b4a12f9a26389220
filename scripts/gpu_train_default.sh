#!/usr/bin/env bash
# Reproduce the shipped checkpoint pixie_gs/data/checkpoints/pixie_default.pt on one GPU box, in one
# command of at most ~10 minutes: generate train/val/test (disjoint seeds via the split salt), train the
# full-feature model with a wall-clock budget, and in parallel the two ablation models (RGB-only and
# occupancy-only inputs, shorter budgets); evaluate all three on the same held-out test split.
# Sizes come from the environment so the same script smoke-tests on a CPU at tiny size:
#   TRAIN_TIERS='10:2000 10:5000' VAL_TIERS='6:3000' TEST_TIERS='5:2000 5:6000' NABL=10 DEVICE=cpu TOTAL_S=400 WORKERS=2 OUT=/tmp/o scripts/gpu_train_default.sh
# and data-parallel over two CPU processes (gloo), as NPROC=2 runs it over two GPUs:
#   NPROC=2 ABLATIONS=0 TRAIN_TIERS='12:2000' VAL_TIERS='6:2000' TEST_TIERS='4:2000' DEVICE=cpu TOTAL_S=200 RESERVE_S=60 \
#     WORKERS=1 EXTRA_TRAIN_ARGS='--resolution 32 --base-channels 8' OUT=/tmp/o scripts/gpu_train_default.sh
set -u -o pipefail
START_TIME=$(date +%s)
OUT=${OUT:?set OUT to the output folder}
NABL=${NABL:-1500}                 # train objects used by each ablation model
ABLATIONS=${ABLATIONS:-1}          # 0: train only the full model (it gets the whole GPU)
DEVICE=${DEVICE:-cuda}; WORKERS=${WORKERS:-16}; TOTAL_S=${TOTAL_S:-570}
DATA=${DATA:-/tmp/pixie_data}; SEED=${SEED:-1}
EXTRA_TRAIN_ARGS=${EXTRA_TRAIN_ARGS:-}
LOAD_S=${LOAD_S:-90}               # time allowed for reading the dataset before training starts
RESERVE_S=${RESERVE_S:-165}        # kept back from TOTAL_S for loading and the test evaluation
EVAL_TIMEOUT_S=${EVAL_TIMEOUT_S:-120}  # the test evaluation's limit (inside RESERVE_S)
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=${OMP_NUM_THREADS:-4}
P="python3 -m pixie_gs.cli.main"
# NPROC > 1 trains the full model data-parallel with torchrun over that many GPUs (DDP; --batch-size stays the
# global batch, split over the processes; docs/training.md, "Several GPUs"); generation and evaluation stay single
NPROC=${NPROC:-1}
TRAIN_P=$P
[ "$NPROC" -gt 1 ] && TRAIN_P="python3 -m torch.distributed.run --standalone --nproc_per_node $NPROC -m pixie_gs.cli.main"
LOG=$OUT/log.txt
mkdir -p "$OUT"
source "$(dirname "$0")/run_steps.sh"   # elapsed, say, train_then_evaluate

say "host: $(nproc --all) cores; $(python3 -c 'import torch;print(torch.__version__, torch.cuda.is_available() and torch.cuda.get_device_name(0))')"
# Each split mixes several Gaussian counts per object (tiers "COUNT:GAUSSIANS"), so the model sees
# sparse and dense splats of every class; parts get distinct seeds, merged round-robin.
TRAIN_TIERS=${TRAIN_TIERS:-"1000:4000 1000:12000 700:30000 300:60000"}
VAL_TIERS=${VAL_TIERS:-"100:4000 100:12000 70:30000 30:60000"}
TEST_TIERS=${TEST_TIERS:-"100:5000 100:20000 100:50000"}
# REUSE_DATA=1 trains on a dataset an earlier run on this machine left in $DATA (made from the same tiers and
# SEED, as $DATA/made_from.txt records), so a second fine-tune in one device session skips generation
# DATA_ONLY=1 makes the dataset and stops (no training)
# GEN_ARGS go to every `pixie generate` call (e.g. GEN_ARGS='--lighting 0' for a control without baked lighting)
GEN_ARGS=${GEN_ARGS:-}
MADE_FROM="SEED=$SEED TRAIN_TIERS=$TRAIN_TIERS VAL_TIERS=$VAL_TIERS TEST_TIERS=$TEST_TIERS GEN_ARGS=$GEN_ARGS"
if [ "${REUSE_DATA:-0}" = 1 ]; then
  [ "$(cat "$DATA/made_from.txt" 2>/dev/null)" = "$MADE_FROM" ] \
    || { say "REUSE_DATA=1 but $DATA was not made from these tiers and seed (see $DATA/made_from.txt)"; exit 1; }
  say "reusing the dataset in $DATA"
else
  rm -f "$DATA/made_from.txt"  # written again only once every split is made: a run cut short leaves none
  rm -rf "$DATA/train" "$DATA/val" "$DATA/test" "$DATA/parts"  # an earlier run's splits (merge_splits makes them anew)
fi
for split in train val test; do
  [ "${REUSE_DATA:-0}" = 1 ] && break
  tiers=$TRAIN_TIERS; [ $split = val ] && tiers=$VAL_TIERS; [ $split = test ] && tiers=$TEST_TIERS
  parts=(); k=0
  for tier in $tiers; do
    # a tier "COUNT:GAUSSIANS:clean" makes its objects as `pixie convert` writes a mesh (`generate --clean`);
    # "COUNT:GAUSSIANS:capture|clean:CLASS,CLASS" draws only those classes (a tier that leans on a few);
    # "COUNT:GAUSSIANS:pairs|clean-pairs" makes every object a pair (`generate --pairs 1`, half the Gaussians each);
    # "COUNT:GAUSSIANS:floors|clean-floors" stands every object on a floor disc (`generate --floors 1`);
    # "COUNT:GAUSSIANS:leftovers" gives every capture-like object interior leftovers (`generate --leftovers 1`);
    # "COUNT:GAUSSIANS:lit" gives every capture-like object baked lighting (`generate --lighting 1`);
    # "COUNT:GAUSSIANS:broadleaf" draws COUNT capture-like trees and keeps the broad-leaved ones (about 15 %,
    # scripts/filter_split.py)
    IFS=: read -r n g look only <<<"$tier"
    gen_args="" keep_shape=""
    case "${look:-capture}" in
      capture) ;; clean) gen_args="--clean" ;; pairs) gen_args="--pairs 1" ;; clean-pairs) gen_args="--clean --pairs 1" ;;
      floors) gen_args="--floors 1" ;; clean-floors) gen_args="--clean --floors 1" ;; leftovers) gen_args="--leftovers 1" ;;
      lit) gen_args="--lighting 1" ;; broadleaf) only=tree keep_shape=broad_leaves ;;
      *) say "unknown tier look '$look' in '$tier' (capture, clean, pairs, clean-pairs, floors, clean-floors, leftovers, lit, broadleaf)"; exit 1 ;;
    esac
    [ -n "${only:-}" ] && gen_args="$gen_args --classes $only"
    part="$DATA/parts/$split$k"
    $P generate "$part" --count $n --split $split --seed $(( SEED * 100 + k )) --workers $WORKERS --gaussians $g $GEN_ARGS $gen_args -q --force \
      >>"$LOG" 2>&1 || { say "generate $split tier $tier failed"; exit 1; }
    if [ -n "$keep_shape" ]; then
      python3 scripts/filter_split.py "$part" $split $keep_shape >>"$LOG" 2>&1 || { say "filter $split tier $tier failed"; exit 1; }
    fi
    parts+=("$part"); k=$((k + 1))
  done
  python3 scripts/merge_splits.py "$DATA" $split "${parts[@]}" >>"$LOG" 2>&1 || { say "merge $split failed"; exit 1; }
  say "generated $split: $tiers"
done
rm -rf "$DATA/parts"
echo "$MADE_FROM" >"$DATA/made_from.txt"
du -sh "$DATA" >>"$LOG"
# DATA_ONLY=1 stops here: the dataset for a run that trains elsewhere (scripts/gpu_two_stage.sh makes stage 2's
# while stage 1 trains)
[ "${DATA_ONLY:-0}" = 1 ] && { say "data only: done"; exit 0; }
NOW=$(elapsed)
FULL_BUDGET=$(( TOTAL_S - NOW - RESERVE_S ))     # leave time for loading + test evaluation
ABL_BUDGET=$(( FULL_BUDGET * 45 / 100 ))
[ "$ABLATIONS" = 0 ] && ABL_BUDGET=0
[ $FULL_BUDGET -lt 30 ] && { say "no time left to train ($FULL_BUDGET s)"; exit 1; }
say "training: full budget ${FULL_BUDGET} s, ablations ${ABL_BUDGET} s each"
# A resumed run (--resume in EXTRA_TRAIN_ARGS, CKPT.state.pt copied into $OUT) counts the seconds trained before
# in its --time-budget-s; add them, so TOTAL_S stays this call's time whatever was trained before.
PRIOR_S=0
if [[ " $EXTRA_TRAIN_ARGS " == *" --resume "* ]]; then  # no state: 0 here, and `pixie train --resume` says so
  PRIOR_S=$(python3 - "$OUT/pixie_default.pt" <<'PY'
import sys
from pixie_gs.model.checkpoint import load_training_state, state_path
side = state_path(sys.argv[1])
print(int(float(load_training_state(side)["elapsed_s"])) if side.exists() else 0)
PY
) || { say "cannot read the training state to resume"; exit 1; }
  say "resuming: ${PRIOR_S} s trained before, up to ${FULL_BUDGET} s more"
fi
train() {  # name inputs budget extra-args...: the trainer's pick evaluated on the test split
  local name=$1 inputs=$2 budget=$3; shift 3
  local launcher=$P prior=0; [ "$name" = pixie_default ] && launcher=$TRAIN_P prior=$PRIOR_S
  train_then_evaluate "$name" "$DATA" "$budget" $prior "$launcher" pick $WORKERS --epochs 200 --inputs $inputs \
    --workers $WORKERS "$@" $EXTRA_TRAIN_ARGS
}
train pixie_default full $FULL_BUDGET &
if [ "$ABLATIONS" != 0 ]; then
  sleep 5
  train ablation_rgb rgb $ABL_BUDGET --limit-train $NABL &
  train ablation_occupancy occupancy $ABL_BUDGET --limit-train $NABL &
fi
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
