#!/usr/bin/env bash
# Two-stage fine-tune on one GPU, one detached run (docs/training.md, "Stop 51" and "Next run (planned after stop
# 51)"). Stage 1 fine-tunes START on broad-leaved plants alone, so the network learns their stems and leaves
# apart; stage 2 trains every kind at a low rate from stage 1's last epoch, as two arms side by side on the same
# GPU (ARM_A, ARM_B: `pixie train` options each), so one run tells which keeps the plants apart and wins the
# other kinds back; ARM_B='' runs arm A alone with the whole GPU. Stage 2's other kinds are generated while
# stage 1 trains; its plants are stage 1's, copied in.
# Launch it through scripts/gpu_train_chain.sh (SCRIPT=scripts/gpu_two_stage.sh) so each device call brings back
# the epoch weights (s1, A, B), the logs and the evaluations on stage 2's test split.
# CPU smoke test (about 4 min on 2 cores):
#   S1_TIERS='60:2000:broadleaf' S1_VAL_TIERS='30:2000:broadleaf' S2_TIERS='20:2000' S2_VAL_TIERS='6:2000' \
#   TEST_TIERS='6:2000' DEVICE=cpu WORKERS=2 S1_BUDGET_S=40 TOTAL_S=400 RESERVE_S=60 \
#   S1_ARGS='--batch-size 4 --epochs 2' ARM_A='--batch-size 4 --lr 3e-4' ARM_B='--batch-size 4 --lr 3e-4 --hue-share 0.5' \
#   OUT=/tmp/two scripts/gpu_two_stage.sh
set -u -o pipefail
START_TIME=$(date +%s)
OUT=${OUT:?set OUT to the output folder}
DEVICE=${DEVICE:-cuda}; WORKERS=${WORKERS:-16}; TOTAL_S=${TOTAL_S:-1000}; RESERVE_S=${RESERVE_S:-90}
LOAD_S=${LOAD_S:-90}               # time allowed for reading a dataset before training starts
START=${START:-$PWD/pixie_gs/data/checkpoints/pixie_default.pt}
S1_TIERS=${S1_TIERS:-"2400:12000:broadleaf 600:30000:broadleaf"}
S1_VAL_TIERS=${S1_VAL_TIERS:-"200:12000:broadleaf"}
S2_TIERS=${S2_TIERS:-"500:4000 550:12000 450:30000 250:60000 125:120000 200:4000:clean 200:12000:clean 150:30000:clean 250:12000:leftovers 150:30000:leftovers 600:12000:capture:tree 200:30000:capture:tree"}
S2_VAL_TIERS=${S2_VAL_TIERS:-"30:4000 35:12000 25:30000 20:12000:clean 40:12000:capture:tree"}
TEST_TIERS=${TEST_TIERS:-"30:8000:clean"}
S1_SEED=${S1_SEED:-40}; S2_SEED=${S2_SEED:-41}
PLANT_COPIES=${PLANT_COPIES:-1}    # times stage 1's plants enter stage 2's train split
S1_BUDGET_S=${S1_BUDGET_S:-240}    # stage 1's training budget, s (its --epochs may end it sooner)
S1_ARGS=${S1_ARGS:-"--batch-size 16 --lr 1e-3 --warmup-steps 20 --hue-share 0 --epochs 16"}
S1_TRAIN=${S1_TRAIN:-1}            # 0: stage 1 makes its plant data but does not train; stage 2 starts from START
                                   # (stage 1 reads real wood ~2 decades softer; docs/training.md, "Stop 58")
ARM_A=${ARM_A:-"--batch-size 16 --lr 3e-4 --hue-share 0 --tilt-deg 40 --tilt-share 0.5"}
ARM_B=${ARM_B-"--batch-size 16 --lr 3e-4 --hue-share 0.5 --tilt-deg 40 --tilt-share 0.5 --distill $START --distill-weight 3 --distill-skip tree,sand,snow_mud,metal_tools,cloth,long_produce"}
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=${OMP_NUM_THREADS:-4}
P="python3 -m pixie_gs.cli.main"
HALF=$(( WORKERS / 2 > 0 ? WORKERS / 2 : 1 ))
D1=$OUT/data_s1 D2O=$OUT/data_s2_other D2=$OUT/data_s2
LOG=$OUT/log.txt
mkdir -p "$OUT"
source "$(dirname "$0")/run_steps.sh"   # elapsed, say, train_then_evaluate
make_data() {  # dir seed train-tiers val-tiers workers: one dataset through gpu_train_default.sh's tiers
  mkdir -p "$1.gen"
  DATA_ONLY=1 DATA=$1 SEED=$2 TRAIN_TIERS=$3 VAL_TIERS=$4 TEST_TIERS=$TEST_TIERS WORKERS=$5 OUT=$1.gen \
    bash scripts/gpu_train_default.sh >/dev/null 2>&1
  local rc=$?; cat "$1.gen/log.txt" >>"$LOG"; return $rc
}
train() {  # name data budget-s extra-args...: train, keep every epoch, evaluate the last on the data's test split
  local name=$1 data=$2 budget=$3; shift 3
  train_then_evaluate "$name" "$data" "$budget" 0 "$P" last $HALF --keep-epochs "$@"
}

say "host: $(nproc --all) cores; $(python3 -c 'import torch;print(torch.__version__, torch.cuda.is_available() and torch.cuda.get_device_name(0))')"
# stage 2's data is the longest job: it starts at once, beside stage 1's data and then stage 1's training
make_data "$D2O" "$S2_SEED" "$S2_TIERS" "$S2_VAL_TIERS" "$HALF" &
gen_pid=$!
make_data "$D1" "$S1_SEED" "$S1_TIERS" "$S1_VAL_TIERS" "$HALF" || { say "stage 1 data failed"; exit 1; }
say "stage 1 data: $(du -sh "$D1" | cut -f1)"
[ "$S1_TRAIN" = 1 ] && train s1 "$D1" "$S1_BUDGET_S" --init "$START" --workers $HALF --seed $S1_SEED $S1_ARGS
wait $gen_pid || { say "stage 2 data failed"; exit 1; }
if [ "$S1_TRAIN" = 1 ]; then
  S1_LAST=$(ls "$OUT" | grep -E '^s1\.epoch[0-9]+\.pt$' | sort -V | tail -1)
  [ -n "$S1_LAST" ] || { say "stage 1 left no epoch"; exit 1; }
  # stage 1's other epochs are not needed (stage 2 starts from the last): removed before any call carries them
  ls "$OUT" | grep -E '^s1\.epoch[0-9]+\.pt$' | grep -vxF "$S1_LAST" | while read -r f; do rm -f "$OUT/$f"; done
  INIT=$OUT/$S1_LAST
else
  say "stage 1 not trained (S1_TRAIN=0): stage 2 starts from $START"
  INIT=$START
fi
# stage 2's data: the other kinds plus stage 1's plants, PLANT_COPIES times in train (copied: merge_splits moves
# the files; more copies raise the plants' share of each epoch, about 10 % with one copy of the default tiers)
copies=()
for k in $(seq 1 "$PLANT_COPIES"); do cp -r "$D1" "$D1.copy$k" && copies+=("$D1.copy$k") || { say "copy failed"; exit 1; }; done
rm -rf "$D2" && mkdir -p "$D2" \
  && python3 scripts/merge_splits.py "$D2" train "$D2O" "${copies[@]}" >>"$LOG" \
  && python3 scripts/merge_splits.py "$D2" val "$D2O" "${copies[0]}" >>"$LOG" \
  && mv "$D2O/test" "$D2/test" && rm -rf "${copies[@]}" || { say "stage 2 merge failed"; exit 1; }
say "stage 2 data: $(du -sh "$D2" | cut -f1); from $(basename "$INIT")"
S2_BUDGET_S=$(( TOTAL_S - $(elapsed) - RESERVE_S - LOAD_S ))
[ $S2_BUDGET_S -lt 30 ] && { say "no time left for stage 2 ($S2_BUDGET_S s)"; exit 1; }
if [ -n "$ARM_B" ]; then
  say "stage 2: two arms, ${S2_BUDGET_S} s each"
  train A "$D2" $S2_BUDGET_S --init "$INIT" --workers $HALF --seed $S2_SEED $ARM_A &
  sleep 5
  train B "$D2" $S2_BUDGET_S --init "$INIT" --workers $HALF --seed $S2_SEED $ARM_B &
  wait
else  # ARM_B='': arm A alone, with the whole GPU and every worker
  say "stage 2: arm A alone, ${S2_BUDGET_S} s"
  train A "$D2" $S2_BUDGET_S --init "$INIT" --workers $WORKERS --seed $S2_SEED $ARM_A
fi
rm -f "$OUT"/*.state.pt "$OUT"/eval_*.txt
say "done"
