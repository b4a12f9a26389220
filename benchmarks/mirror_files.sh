# Sourced by the real sets' fetch scripts (real_holdout/rh_fetch.sh, real_third/r3_fetch.sh) and
# scripts/teacher_pool_fetch.sh: copy published
# files out of git mirrors of their source repositories, at a given commit. Needs M (the mirror root, laid out
# as the fetch tool does: M/owner+name/repo[/.git]).
# mirror_git_dir REPO: the git directory of the mirror of REPO ("owner+name")
mirror_git_dir() { local d="$M/$1/repo"; [ -d "$d/.git" ] && d="$d/.git"; echo "$d"; }
# show REPO COMMIT PATH DEST: write the file PATH of REPO at COMMIT to DEST (folders made as needed)
show() { mkdir -p "$(dirname "$4")"; git --git-dir="$(mirror_git_dir "$1")" show "$2:$3" > "$4"; }
# gltf_with_uris REPO COMMIT DIR_IN_REPO NAME.gltf DEST_DIR: the .gltf and every "uri" it names (no data: URIs)
gltf_with_uris() {
  show "$1" "$2" "$3/$4" "$5/$4"
  python3 - "$5/$4" <<'PY' | while IFS= read -r uri; do show "$1" "$2" "$3/$uri" "$5/$uri"; done
import json, sys
doc = json.load(open(sys.argv[1]))
for entry in doc.get("buffers", []) + doc.get("images", []):
    uri = entry.get("uri", "")
    if uri and not uri.startswith("data:"):
        print(uri)
PY
}
