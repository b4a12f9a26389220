# Steps shared by the GPU run scripts (gpu_train_default.sh, gpu_two_stage.sh); sourced, not run.
# The caller sets OUT (output folder), LOG, START_TIME (epoch seconds at the start), P (the pixie command),
# DEVICE and LOAD_S (seconds allowed for reading a dataset before training starts); EVAL_TIMEOUT_S (default
# 180) bounds each evaluation.

elapsed() { echo $(( $(date +%s) - START_TIME )); }
say() { echo "[$(elapsed) s] $*" | tee -a "$LOG"; }

# train_then_evaluate NAME DATA BUDGET_S PRIOR_S LAUNCHER EVAL EVAL_WORKERS [train options...]
# `LAUNCHER train DATA --out $OUT/NAME.pt` for at most BUDGET_S of training in this call (killed after BUDGET_S +
# LOAD_S; its --time-budget-s adds PRIOR_S, the seconds a resumed run trained before),
# then `pixie evaluate` on DATA's test split into $OUT/eval_NAME.json (and .txt, copied into the log). EVAL
# names the weights evaluated: `pick` the trainer's pick NAME.pt, `last` the last epoch kept (--keep-epochs).
train_then_evaluate() {
  local name=$1 data=$2 budget=$3 prior=$4 launcher=$5 eval=$6 eval_workers=$7; shift 7
  timeout $(( budget + LOAD_S )) $launcher train "$data" --out "$OUT/$name.pt" --device "$DEVICE" \
    --time-budget-s $(( budget + prior )) --log-json "$OUT/train_$name.json" -q "$@" >>"$LOG" 2>&1 \
    && say "trained $name" || say "train $name failed"
  local weights=$name.pt
  [ "$eval" = last ] && weights=$(ls "$OUT" | grep -E "^$name\.epoch[0-9]+\.pt$" | sort -V | tail -1)
  [ -n "$weights" ] && [ -f "$OUT/$weights" ] || { say "evaluate $name: no weights"; return 0; }
  timeout "${EVAL_TIMEOUT_S:-180}" $P evaluate "$OUT/$weights" "$data" --split test --device "$DEVICE" \
    --workers "$eval_workers" -q --json "$OUT/eval_$name.json" >"$OUT/eval_$name.txt" 2>&1 \
    && say "evaluated $weights" || say "evaluate $name failed"
  cat "$OUT/eval_$name.txt" >>"$LOG"
}
