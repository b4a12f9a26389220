#!/usr/bin/env bash
# The detail-level pairs of benchmarks/bench_lod_consistency.py: 20 objects of marcelpadilla/splats (CC BY 4.0),
# each published by its mesh2splat tool at 10k and at 100k Gaussians (NAME_10k.splat, NAME_100k.splat), copied out
# of a git mirror at a fixed commit. Not shipped; not in the three benchmark real sets (they are the teacher pool's
# sources too, scripts/teacher_pool_fetch.sh, at 100k: a model trained with that pool has seen these objects).
# usage: lod_pairs_fetch.sh OUT_DIR [MIRROR_ROOT]
set -euo pipefail
OUT=${1:?usage: lod_pairs_fetch.sh OUT_DIR [MIRROR_ROOT]}
M=${2:-/work/.mirror}
mkdir -p "$OUT"
source "$(dirname "$0")/mirror_files.sh"   # show REPO COMMIT PATH DEST
MP=marcelpadilla+splats;             MPC=a0f0dc0893dd51a0676e813ffcc742a3f31f6cb3
for o in boot cheese hammer mushroom pizza strawberry teapot violin sword ring wingnut parsnip tree house well \
         skull fish spot boat falconstatue; do
  for lod in 10k 100k; do show $MP $MPC data/$o/${o}_$lod.splat "$OUT/${o}_$lod.splat"; done
done
echo "done: $OUT"
