#!/usr/bin/env bash
# The GPU side of issues 14 and 16 on one lent GPU box, in parts that each fit one device call:
#   tests     the physics, simulator (column P2G included) and feature-field tests on CUDA (~3-4 min)
#   simtests  the same without the feature-field tests (every CUDA sim test)   (~3 min)
#   sim       MPM throughput at 1M and 4M particles, random input sorted by the solver, 3 frames: the
#             default (column P2G carrying affine matrices, blocks of 128) against the chunked P2G,
#             the previous default, on the same frames                          (~1 min)
#   diagnose  the 20k-Gaussian, 2-second diagnose runtime case (target <= 5 s), twice in one
#             process, with its timeline of simulations                         (~1 min)
#   diagnose-ab  the batched-solver tests on CUDA, then the runtime case once with its frames on the
#             device (conditional graphs), once with single-substep graphs and the output imports
#             timed (A/B against `diagnose`; `--profile 45` gives a cProfile)   (~1 min)
#   batch     the model process alone, then 1,000 assets of 100k Gaussians in batch mode (>= 10/s)  (~5 min)
#   p2g       the column P2G's CUDA tests, then the default and the column/slab variants against the
#             chunked P2G on the same frames at 1M and 4M particles (issue 14)   (~4 min)
# usage, from the repo root, Warp on PYTHONPATH for tests/sim/diagnose (batch needs none):
#   OUT=/tmp/gpu scripts/gpu_benchmarks.sh simtests sim         # one call (~4 min)
#   OUT=/tmp/gpu scripts/gpu_benchmarks.sh diagnose             # another
#   OUT=/tmp/gpu scripts/gpu_benchmarks.sh batch                # a second call
# Full logs go to $OUT/<part>.txt; the terminal gets the figures that decide each target.
set -u -o pipefail
OUT=${OUT:?set OUT to the output folder}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
# what the box lacks (plyfile, trimesh, tqdm) comes from wheels in an ignored .whl* folder, if carried
if ! python3 -c "import plyfile, trimesh, tqdm" 2>/dev/null && ls .whl*/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --target /tmp/pixie_site .whl*/*.whl >"$OUT/wheels.txt" 2>&1
  export PYTHONPATH=/tmp/pixie_site:${PYTHONPATH:-}
fi
export PYTHONPATH=$PWD:${PYTHONPATH:-}
SIM_TESTS="tests/test_sim_kernels.py tests/test_sim_p2g_column.py tests/test_sim_physics.py tests/test_sim_state.py
  tests/test_sim_batched.py tests/test_sim_rigid.py"
cuda_tests() {  # log name, time limit (s), test files: failures and the summary to the terminal
  local log=$OUT/$1.txt limit=$2
  shift 2
  PIXIE_TEST_DEVICES=cuda timeout "$limit" python3 -m pytest -q -p no:cacheprovider "$@" >"$log" 2>&1
  grep -E "^(FAILED|ERROR)" "$log" | cut -c1-300
  tail -3 "$log"
}
run_part() {
  case $1 in
    tests)
      # shellcheck disable=SC2086
      cuda_tests tests 270 $SIM_TESTS tests/test_field_device.py ;;
    simtests)
      # shellcheck disable=SC2086
      cuda_tests simtests 240 $SIM_TESTS ;;
    sim)
      timeout 150 python3 benchmarks/bench_sim_throughput.py --device cuda --sizes 1000000 4000000 \
        --order sorted --frames 3 --variant chunked --variant auto >"$OUT/sim.txt" 2>&1
      grep -E "^device" "$OUT/sim.txt" | cut -c1-160
      grep -E "^warp|per substep|vs baseline|issue 14" "$OUT/sim.txt" | sed -E 's/ \(kernels alone.*//; s/\[.*//' \
        | cut -c1-230 ;;
    diagnose)
      timeout 110 python3 benchmarks/bench_diagnose.py --part runtime --device cuda --repeat 2 \
        >"$OUT/diagnose.txt" 2>&1
      grep -E "imports for|diagnosis incl|named:|per stage" "$OUT/diagnose.txt" | cut -c1-400 ;;
    diagnose-ab)
      PIXIE_TEST_DEVICES=cuda timeout 45 python3 -m pytest -q -p no:cacheprovider tests/test_sim_batched.py \
        >"$OUT/diagnose_tests.txt" 2>&1
      tail -2 "$OUT/diagnose_tests.txt"
      timeout 25 python3 benchmarks/bench_diagnose.py --part runtime --device cuda --device-loop on \
        >"$OUT/diagnose_loop.txt" 2>&1
      grep -E "runtime:|diagnosis incl|named:|per stage" "$OUT/diagnose_loop.txt" | cut -c1-400
      timeout 20 python3 benchmarks/bench_diagnose.py --part runtime --device cuda --graph-substeps 1 \
        --imports timed >"$OUT/diagnose_ab.txt" 2>&1
      grep -E "runtime:|diagnosis incl|named:" "$OUT/diagnose_ab.txt" | cut -c1-300 ;;
    batch)
      timeout 90 python3 benchmarks/bench_model_step.py --count 24 --device cuda --threads 1,2,3 \
        >"$OUT/model_step.txt" 2>&1
      tail -6 "$OUT/model_step.txt"
      timeout 330 python3 benchmarks/bench_batch_annotate.py --count 1000 --gaussians 100000 --device cuda \
        --pools process --workers 12 --model-threads 3 --loop-files 3 --budget-s 230 >"$OUT/batch.txt" 2>&1
      tr '\r' '\n' <"$OUT/batch.txt" | grep -E "assets/s|CPU time|byte-identical|threads \(most" | tail -10 ;;
    p2g)
      PIXIE_TEST_DEVICES=cuda timeout 110 python3 -m pytest -q -p no:cacheprovider tests/test_sim_p2g_column.py \
        tests/test_sim_kernels.py >"$OUT/p2g_tests.txt" 2>&1
      grep -E "^(FAILED|ERROR)" "$OUT/p2g_tests.txt" | cut -c1-300
      tail -3 "$OUT/p2g_tests.txt"
      timeout 125 python3 benchmarks/bench_sim_throughput.py --device cuda --sizes 1000000 4000000 --order sorted \
        --frames 3 --variant chunked --variant auto --variant column,carry --variant column --variant column,novec \
        --variant column,carry,run=64 --variant slab,carry >"$OUT/p2g_sim.txt" 2>&1
      grep -E "^device" "$OUT/p2g_sim.txt" | cut -c1-160
      grep -E "^warp|per substep|vs baseline|issue 14" "$OUT/p2g_sim.txt" | sed -E 's/ \(kernels alone.*//; s/\[.*//' \
        | cut -c1-190 ;;
    *) echo "unknown part $1 (tests, simtests, sim, diagnose, diagnose-ab, batch, p2g)"; return 2 ;;
  esac
}
for part in "$@"; do
  echo "== $part ($(date -u +%H:%M:%S))"
  run_part "$part" || echo "$part: exit $?"
done
