#!/usr/bin/env bash
# Sources of the teacher pool (pixie_gs/dataset/teacher_pool.py): real scans and other tools' splats, none of
# them in the three benchmark real sets (../shared/real, benchmarks/real_holdout, benchmarks/real_third), copied
# out of git mirrors at fixed commits; the glTF meshes are turned into splats with `pixie convert` (default flags).
# Licences: marcelpadilla/splats CC BY 4.0 (its LICENSE); RobotLocomotion/models manipulation_station BSD 3-Clause
# (its LICENSE.txt), dishes and tri_homecart BSD (Toyota Research Institute, their LICENSE). Used for training
# only; nothing of them is shipped. (The YCB scans of eleramp/pybullet-object-models were meant too, but the
# mirror lists their textures and meshes without the blobs.)
# usage: teacher_pool_fetch.sh OUT_DIR [MIRROR_ROOT]   (then: python -m pixie_gs.dataset.teacher_pool POOL $OUT/*.splat $OUT/*.ply)
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
# RobotLocomotion/models: a bin and shelves (read as metal by r58), a table, a bowl, a plate and a cutting board
RL=RobotLocomotion+models;           RLC=4723170e1c8ee8bc59c342bb5c491ab8f263f1fb
gltf_with_uris $RL $RLC manipulation_station/assets bin.gltf "$OUT/src/bin"
gltf_with_uris $RL $RLC manipulation_station/assets shelves.gltf "$OUT/src/shelves"
gltf_with_uris $RL $RLC manipulation_station/assets table_wide.gltf "$OUT/src/table_wide"
gltf_with_uris $RL $RLC dishes/assets evo_bowl.gltf "$OUT/src/evo_bowl"
gltf_with_uris $RL $RLC dishes/assets plate_8in.gltf "$OUT/src/plate_8in"
gltf_with_uris $RL $RLC tri_homecart/assets homecart_cutting_board.gltf "$OUT/src/cutting_board"
PIXIE=${PIXIE:-pixie}
for o in bin shelves table_wide evo_bowl plate_8in cutting_board; do
  $PIXIE convert "$(ls "$OUT/src/$o"/*.gltf)" "$OUT/$o.ply" -q --force
done
echo "done: $OUT"
