#!/usr/bin/env bash
# A training run longer than one device call (each call ends within 10 minutes; a warm machine keeps its
# processes and files for ~30 s after a call, so back-to-back calls see the same run):
#   start   install the wheels carried in .whl_model (plyfile, trimesh, tqdm), launch
#           $SCRIPT (default scripts/gpu_train_default.sh) detached (setsid, survives the call) with its output in $RUN,
#           then watch it
#   watch   watch the run again
# Each call returns after WATCH_S seconds or when the run ends, whichever comes first, and copies the
# run's checkpoint, its training state, the per-epoch log and the test evaluation into $OUT (with
# --keep-epochs also the epoch weights not sent before, in epochs_NN-MM.tar; `tar -xf` them here), so a machine
# lost between calls costs only the time since the last copy. It also copies them every SNAP_S seconds while it
# watches (default 60), so a call cut short at the device's limit still brings back what the run had made.
# The run's options are the environment of gpu_train_default.sh (TOTAL_S, TRAIN_TIERS, EXTRA_TRAIN_ARGS, …),
# given to `start`.
# usage (repo root, device call):  RUN=/root/run WATCH_S=540 OUT=$OUT scripts/gpu_train_chain.sh start
#                                  RUN=/root/run WATCH_S=570 OUT=$OUT scripts/gpu_train_chain.sh watch
# CPU smoke test: RUN=/tmp/r WATCH_S=120 DEVICE=cpu WORKERS=2 TOTAL_S=300 TRAIN_TIERS='26:2000' VAL_TIERS='8:2000' \
#   TEST_TIERS='8:2000' EXTRA_TRAIN_ARGS='--resolution 32 --base-channels 8' OUT=/tmp/o scripts/gpu_train_chain.sh start
set -u -o pipefail
mode=${1:?usage: gpu_train_chain.sh start|watch}
OUT=${OUT:?set OUT to the folder that comes back}
RUN=${RUN:-/root/run}
WATCH_S=${WATCH_S:-540}
SCRIPT=${SCRIPT:-scripts/gpu_train_default.sh}  # the run to launch (scripts/gpu_two_stage.sh for the two-stage run)
EPOCHS_PER_TAR=${EPOCHS_PER_TAR:-6}   # --keep-epochs weights per tar sent back (≤ 16 MiB a file)
SNAP_S=${SNAP_S:-60}                  # seconds between the copies into $OUT while watching
T0=$(date +%s)
mkdir -p "$OUT"

if [ "$mode" = start ]; then
  mkdir -p "$RUN"
  if ! python3 -c "import plyfile, trimesh, tqdm" 2>/dev/null; then
    python3 -m pip install -q --no-index --no-deps --target "$RUN/site" .whl_model/*.whl >"$RUN/wheels.txt" 2>&1 \
      || { echo "wheel install failed"; cat "$RUN/wheels.txt"; exit 1; }
    export PYTHONPATH=$RUN/site:${PYTHONPATH:-}
  fi
  export PYTHONPATH=$PWD:${PYTHONPATH:-}
  nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null
  OUT=$RUN setsid nohup bash "$SCRIPT" >"$RUN/daemon.txt" 2>&1 < /dev/null &
  echo $! >"$RUN/pid"
  echo "started run in $RUN (pid $(cat "$RUN/pid"))"
elif [ "$mode" != watch ]; then
  echo "unknown mode $mode (start, watch)"; exit 2
elif [ ! -f "$RUN/pid" ]; then
  # a fresh machine (the last one was given back between calls): the run is gone, not finished
  echo "no run in $RUN on this machine: it was lost between calls; resume it from the last copy in \$OUT"
  echo "(copy CKPT and CKPT.state.pt into $RUN, add --resume to EXTRA_TRAIN_ARGS, call start again with TOTAL_S"
  echo " the time of that call: the time trained before is added to the run's budget)"
  exit 3
fi

running() { kill -0 "$(cat "$RUN/pid" 2>/dev/null)" 2>/dev/null; }
put() {  # put SRC NAME: SRC into $OUT/NAME whole or not at all (a call cut mid-copy leaves the last whole copy)
  cp "$1" "$OUT/$2.part" && mv -f "$OUT/$2.part" "$OUT/$2"
}
snapshot() {  # final (1: the call's last copy, which marks the epochs it sent; 0: a copy while watching)
  # at most 8 files come back per call (16 MiB each): the fixed files here (daemon.txt stays on the machine;
  # log.txt has its lines), any other JSON files of the run in one json.tar, and the --keep-epochs weights not
  # sent before in tars of up to EPOCHS_PER_TAR (2.5 MB each), one stem per tar (epochs_NN-MM.tar for
  # pixie_default, epochs_STEM_NN-MM.tar for others) in the slots left. Each copy replaces the last one's tars
  # (the same epochs and more), so the files in $OUT stay within the limit however often it copies.
  local final=$1 sent f
  for f in pixie_default.pt pixie_default.pt.state.pt train_pixie_default.json train_logs.json eval_pixie_default.json log.txt; do
    if [ -f "$RUN/$f" ]; then put "$RUN/$f" "$f"; else rm -f "$OUT/$f"; fi  # gone since the last copy: merged
  done
  local others=()
  for f in $(ls "$RUN" | grep -E '\.json$'); do
    case "$f" in train_pixie_default.json|train_logs.json|eval_pixie_default.json) ;; *) others+=("$f") ;; esac
  done
  mkdir -p "$RUN/snap"
  if [ ${#others[@]} -gt 0 ]; then
    tar -cf "$RUN/snap/json.tar" -C "$RUN" "${others[@]}" && put "$RUN/snap/json.tar" json.tar
  else
    rm -f "$OUT/json.tar"
  fi
  sent=$(ls "$OUT" | grep -cvE '^epochs_.*\.tar$')  # the slots the tars may not take
  local new=()
  for f in $(ls "$RUN" | grep -E '^[A-Za-z0-9_-]+\.epoch[0-9]+\.pt$' | sort -V); do  # stem, then epoch order
    grep -qxF "$f" "$RUN/epochs_sent.txt" 2>/dev/null || new+=("$f")
  done
  local i=0 stem chunk first last name tars=()
  while [ $i -lt ${#new[@]} ] && [ $sent -lt 8 ]; do
    stem=${new[$i]%%.epoch*}; chunk=()
    while [ $i -lt ${#new[@]} ] && [ ${#chunk[@]} -lt "$EPOCHS_PER_TAR" ] && [ "${new[$i]%%.epoch*}" = "$stem" ]; do
      chunk+=("${new[$i]}"); i=$((i + 1))
    done
    first=${chunk[0]#"$stem".epoch} last=${chunk[-1]#"$stem".epoch}
    name=epochs_${first%.pt}-${last%.pt}.tar; [ "$stem" = pixie_default ] || name=epochs_${stem}_${first%.pt}-${last%.pt}.tar
    tar -cf "$RUN/snap/$name" -C "$RUN" "${chunk[@]}" && put "$RUN/snap/$name" "$name" || continue
    sent=$((sent + 1)); tars+=("$name")
    [ "$final" = 1 ] && printf '%s\n' "${chunk[@]}" >>"$RUN/epochs_sent.txt"
  done
  for f in $(ls "$OUT" | grep -E '^epochs_.*\.tar$'); do  # an earlier copy's tars, now inside the new ones
    printf '%s\n' "${tars[@]}" | grep -qxF "$f" || rm -f "$OUT/$f"
  done
  rm -rf "$RUN/snap"
  [ "$final" = 1 ] || return 0
  python3 - "$RUN" <<'PY' || true
import json, pathlib, sys
run = pathlib.Path(sys.argv[1])
for name in ("train_pixie_default.json", "train_logs.json"):
    p = run / name
    if p.exists():
        d = json.loads(p.read_text())
        meta = d.get("meta", d.get("pixie_default", {}).get("meta", {}))
        for h in meta.get("history", []):
            print("epoch", h.get("epoch"), {k: (round(v, 4) if isinstance(v, float) else v) for k, v in h.items()
                                              if k in ("elapsed_s", "train_loss", "val_loss", "train_objects_per_s", "val_accuracy", "val_mse_avg")})
        break
PY
}
last_copy=$(date +%s)
while running && [ $(( $(date +%s) - T0 )) -lt "$WATCH_S" ]; do
  sleep 10
  if [ $(( $(date +%s) - last_copy )) -ge "$SNAP_S" ]; then snapshot 0; last_copy=$(date +%s); fi
done
snapshot 1
tail -5 "$RUN/log.txt" 2>/dev/null
running && echo "run still going after $(( $(date +%s) - T0 )) s of this call" || echo "run finished"
