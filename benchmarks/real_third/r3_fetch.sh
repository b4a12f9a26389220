#!/usr/bin/env bash
# Re-extract the third real set (benchmarks/real_third) from git mirrors of its source repositories.
# usage: r3_fetch.sh OUT_DIR [MIRROR_ROOT]
#   MIRROR_ROOT holds bare/normal clones named owner+name (default /work/.mirror, as the fetch tool lays them
#   out: /work/.mirror/owner+name/repo[/.git]). Without mirrors: git clone the repos below and point at them.
# Meshes in glTF are copied as published. The OBJ scans (YCB banana and scissors, odedstein hammer and stuffed
# toy, MuJoCo mug) are copied as published under src/ and then turned into the splat PLY the benchmark reads with
# `pixie convert SRC.obj STEM.ply` (default flags, seed 0): bench_real_set.py's source_for() takes a .ply
# named after the entry as the splat itself, and has no OBJ path.
set -euo pipefail
OUT=${1:?usage: r3_fetch.sh OUT_DIR [MIRROR_ROOT]}
M=${2:-/work/.mirror}
mkdir -p "$OUT"
source "$(dirname "$0")/../mirror_files.sh"   # show REPO COMMIT PATH DEST

RL=RobotLocomotion+models;           RLC=4723170e1c8ee8bc59c342bb5c491ab8f263f1fb
KH=sbtron+glTF-Sample-Models;        KHC=5bdbcd0b7dced77c7dbb0e5772426bb23f937c1e
YC=eleramp+pybullet-object-models;   YCC=57cc4007607f6bcbb0a5364ccab7636faf7a91e4
OS=odedstein+meshes;                 OSC=835213277571d625722d25880c9c3010c6f45a5a

# Poly Haven (CC0) and TRI tutorial (CC0) glTFs: STEM/STEM.gltf with .bin and textures/ at their relative paths
A=tutorials/models/assets
for stem in wooden_bookshelf_worn_1k painted_wooden_cabinet_02_1k; do
  base=${stem%_1k}
  show $RL $RLC $A/$stem.gltf "$OUT/$stem/$stem.gltf"
  show $RL $RLC $A/$base.bin  "$OUT/$stem/$base.bin"
  for t in nor_gl diff arm; do show $RL $RLC $A/textures/${base}_${t}_1k.jpg "$OUT/$stem/textures/${base}_${t}_1k.jpg"; done
done
show $RL $RLC $A/curtain_open.gltf "$OUT/curtain_open/curtain_open.gltf"
show $RL $RLC $A/curtain_open.bin  "$OUT/curtain_open/curtain_open.bin"
for t in curtain_normal curtain_diffuse; do show $RL $RLC $A/textures/$t.png "$OUT/curtain_open/textures/$t.png"; done

# Khronos sample BoomBox (CC0), the pbrSpecularGlossiness folder (the only one whose files are all under 4 MiB)
B=2.0/BoomBox/glTF-pbrSpecularGlossiness
show $KH $KHC $B/BoomBox.gltf "$OUT/BoomBox/BoomBox.gltf"
show $KH $KHC $B/BoomBox.bin  "$OUT/BoomBox/BoomBox.bin"
for t in baseColor roughnessMetallic normal emissive occlusion diffuse specularGlossiness; do
  show $KH $KHC $B/BoomBox_$t.png "$OUT/BoomBox/BoomBox_$t.png"; done

# OBJ scans -> src/, then converted
Y=pybullet_object_models/ycb_objects
for o in YcbBanana YcbScissors; do
  for f in textured_simple_reoriented.obj textured_simple_reoriented.mtl texture_map.png; do
    show $YC $YCC $Y/$o/$f "$OUT/src/$o/$f"; done
done
for o in hammer stuffedtoy; do show $OS $OSC objects/$o/$o.obj "$OUT/src/$o/$o.obj"; done
# MuJoCo's textured mug: mug.obj names "./mug.obj.mtl", which the repository does not ship (its mug.xml binds
# mug.png as the texture instead); this three-line material file, written here, does the same for the OBJ.
MJ=google-deepmind+mujoco;           MJC=a7255075b003506ff5f34b512d88e02df12a73c6
show $MJ $MJC model/mug/mug.obj "$OUT/src/mug/mug.obj"
show $MJ $MJC model/mug/mug.png "$OUT/src/mug/mug.png"
printf 'newmtl material_0\nKd 1.0 1.0 1.0\nmap_Kd mug.png\n' > "$OUT/src/mug/mug.obj.mtl"

PIXIE=${PIXIE:-pixie}
for o in YcbBanana YcbScissors; do $PIXIE convert "$OUT/src/$o/textured_simple_reoriented.obj" "$OUT/$o.ply" -q --force; done
for o in hammer stuffedtoy mug; do $PIXIE convert "$OUT/src/$o/$o.obj" "$OUT/$o.ply" -q --force; done
echo "done: $OUT"
