#!/usr/bin/env bash
# Re-extract the second real set (benchmarks/real_holdout) from git mirrors of its source repositories, as
# PROVENANCE.txt lists them (files, commits); then `sha256sum` them against that list if you want to be sure.
# usage: rh_fetch.sh OUT_DIR [MIRROR_ROOT]
#   MIRROR_ROOT holds clones named owner+name (default /work/.mirror, as the fetch tool lays them out:
#   /work/.mirror/owner+name/repo[/.git]). Without mirrors: git clone the repositories below and point at them.
# Files are copied as published; a .gltf asset goes in its own folder with every buffer and image its JSON names,
# at their relative paths (the layout bench_real_set.py's source_for() reads).
set -euo pipefail
OUT=${1:?usage: rh_fetch.sh OUT_DIR [MIRROR_ROOT]}
M=${2:-/work/.mirror}
mkdir -p "$OUT"
source "$(dirname "$0")/../mirror_files.sh"   # show REPO COMMIT PATH DEST
PC=playcanvas+engine; EX=examples/assets
show $PC 7b4f9c0c08a3a22e9c9197a300ab75ca613ed24f $EX/splats/biker.compressed.ply "$OUT/biker.compressed.ply"
show $PC 54aa6105d70f17b238e0f6c1cb69abe460b8712a $EX/models/cat.glb "$OUT/cat.glb"
show $PC e1fe332a6cef0bbacf0e25f76748a022de492c51 $EX/models/statue.glb "$OUT/statue.glb"
show $PC 50c9e89d0ca26e5d00d438a7501d0dada4df1771 $EX/models/SunglassesKhronos.glb "$OUT/SunglassesKhronos.glb"
show $PC 0aaef5e432c4797ed23c1f966e2cc43232ec0613 $EX/models/glass-table.glb "$OUT/glass-table.glb"
show haakongarfjell+splat-files 5126efba1c983cb6f483b1642779ced4271305be chair_gaussian.splat "$OUT/chair_gaussian.splat"
show aleph-viewer+gltf-models 434b4e6de72a65bbc8b0b23e4532463b475093ac white-claw-can.glb "$OUT/white-claw-can.glb"
show thmslhst+railbird bba8fa8bc3267935ba358afd745399952ed94f89 public/burger-from-amboy.spz "$OUT/burger-from-amboy.spz"
show marcelpadilla+splats a0f0dc0893dd51a0676e813ffcc742a3f31f6cb3 data/plant/plant.splat "$OUT/plant.splat"

KH=sbtron+glTF-Sample-Models
show $KH 3787f278ea4a562f102ded6d510178ead3065a2d 2.0/DamagedHelmet/glTF-Binary/DamagedHelmet.glb "$OUT/DamagedHelmet.glb"
gltf_with_uris $KH 5bdbcd0b7dced77c7dbb0e5772426bb23f937c1e 2.0/Avocado/glTF Avocado.gltf "$OUT"

RL=RobotLocomotion+models; RLC=4723170e1c8ee8bc59c342bb5c491ab8f263f1fb
for stem in tea_set_01_1k sofa_03_1k painted_wooden_stool_1k wooden_table_02_1k; do
  gltf_with_uris $RL $RLC tutorials/models/assets $stem.gltf "$OUT/$stem"
done
gltf_with_uris $RL $RLC veggies/assets yellow_bell_pepper_no_stem_low.gltf "$OUT/yellow_bell_pepper_no_stem_low"
echo "done: $OUT"
