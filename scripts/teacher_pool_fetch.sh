#!/usr/bin/env bash
# Sources of the teacher pool (pixie_gs/dataset/teacher_pool.py): real scans and other tools' splats, none of
# them in the three benchmark real sets (../shared/real, benchmarks/real_holdout, benchmarks/real_third), copied
# out of a git mirror at a fixed commit. Licence: marcelpadilla/splats, CC BY 4.0 (its LICENSE); used for training
# only, nothing of it is shipped. (The YCB scans of eleramp/pybullet-object-models were meant too, but the mirror
# lists their textures and meshes without the blobs.)
# usage: teacher_pool_fetch.sh OUT_DIR [MIRROR_ROOT]   (then: python -m pixie_gs.dataset.teacher_pool make …)
set -euo pipefail
OUT=${1:?usage: teacher_pool_fetch.sh OUT_DIR [MIRROR_ROOT]}
M=${2:-/work/.mirror}
mkdir -p "$OUT"
source "$(dirname "$0")/../benchmarks/mirror_files.sh"   # show REPO COMMIT PATH DEST

# marcelpadilla/splats: one capture and mesh2splat splats at their 100k level (its plant capture is in the
# second real set and left out)
MP=marcelpadilla+splats;             MPC=a0f0dc0893dd51a0676e813ffcc742a3f31f6cb3
show $MP $MPC data/academic_tarot_cards/academic_tarot_cards.splat "$OUT/academic_tarot_cards.splat"
for o in boot cheese hammer mushroom pizza strawberry teapot violin sword ring wingnut parsnip tree house well \
         skull fish spot boat falconstatue cat cow koala penguin plane demosthenes goathead lucy happy dragon \
         stanford_bunny torus tower brucewick bob armadillo scorpion; do
  show $MP $MPC data/$o/${o}_100k.splat "$OUT/${o}_100k.splat"
done
echo "done: $OUT"
