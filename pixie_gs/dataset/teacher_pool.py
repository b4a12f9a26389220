"""A training split of real splats and scans labelled by a teacher checkpoint (`pixie train --teacher-pool`).

Why: every fine-tune on generated objects alone moved the readings of real captures (the development set's
redplant is lost after one epoch of r62; docs/model_card.md), and holding the teacher's outputs on
*generated* objects of the old kinds did not hold them (docs/training.md, the CPU proxies of `--distill`).
This pool brings captures of the real world into the training set with the teacher's own readings as their
labels. Each source is prepared as `pixie annotate` prepares a capture (floaters, up, ground, objects), each
object turned upright (its up vector to +z, as the network sees it), cut to its robust box, optionally thinned
and labelled per Gaussian with the teacher's materials. With
`pixie train --distill TEACHER` the student is also held to the teacher's soft outputs on these objects
(their kind is `POOL_CLASS`, not skipped). Sources must be kept apart from every benchmark set.

usage:
  python -m pixie_gs.dataset.teacher_pool OUT_DIR SOURCE [SOURCE ...] [--checkpoint CKPT] [--max-gaussians N]
then `pixie train DATA --teacher-pool OUT_DIR --teacher-pool-repeat K --distill CKPT …` adds its objects, each
listed K times, to DATA's train split.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from ..atomic import StagedDirectory
from ..errors import InputError
from ..materials import MATERIAL_NAMES
from ..prepare.updir import turn
from ..splat import SplatCloud, quat_to_rotmat, rotmat_to_quat
from .generate import INDEX_NAME
from .labels import table_extremes

POOL_CLASS = "real_pool"  # the kind of every pool object (`--distill-skip` does not name it: it is distilled)
POOL_SPLIT = "train"
BOX_SLACK = 0.02  # the robust box is widened by this share of its size before cutting (keeps the rim)


def inside_box(points: np.ndarray, box: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Indices of the `points` (N,3) that lie in `box` (lo, hi) widened by BOX_SLACK of its size on every side."""
    lo, hi = np.asarray(box[0], np.float64), np.asarray(box[1], np.float64)
    pad = BOX_SLACK * (hi - lo)
    return np.nonzero(np.all((points >= lo - pad) & (points <= hi + pad), axis=1))[0]


def turned_cloud(cloud: SplatCloud, rotation: np.ndarray) -> SplatCloud:
    """A copy of `cloud` turned by the proper rotation `rotation` (3,3): centres and Gaussian orientations.
    View-dependent colour is kept as stored: its energy per degree, the only SH feature the network reads,
    does not change under a rotation."""
    out = cloud.copy()
    out.means = turn(cloud.means.astype(np.float64), rotation).astype(np.float32)
    out.rotations = rotmat_to_quat(rotation[None] @ quat_to_rotmat(cloud.quats)).astype(np.float32)
    return out


def labelled_objects(cloud: SplatCloud, checkpoint: str | None, device: str, max_gaussians: int | None = None,
                     seed: int = 0) -> list[SplatCloud]:
    """The prepared objects of one capture, upright, thinned at random to at most `max_gaussians` each (None:
    all kept) and labelled with the teacher's materials *on that upright object* (material_id, E Pa, ν,
    density kg/m³; part_id 0), so the label loss and the distillation term ask for the same reading.

    Thinning changes the reading: r58 reads a 100k-Gaussian splat thinned to 12k up to 0.85 decades of E apart,
    and a converted bin and shelves as metal whole but elastic at 25k (docs/model_card.md, "Candidates r64 and
    r65"); it only serves to make a pool small enough to carry."""
    from ..annotate import annotate_cloud
    from ..prepare import prepare_cloud

    prepared_cloud, scene = prepare_cloud(cloud)  # `pixie annotate`'s defaults
    rotation = scene.rotation()  # up vector to +z, as predict_materials turns it
    object_id = prepared_cloud.get("object_id").astype(np.int64)
    rng = np.random.default_rng(seed)
    extremes = table_extremes()  # read once per capture, not per object
    objects = []
    for obj in scene.objects:
        mine = np.nonzero(object_id == obj.object_id)[0]
        if len(mine) == 0:
            continue
        plain = cloud.subset(mine)
        upright = turned_cloud(SplatCloud.from_arrays(plain.means, plain.log_scales, plain.rotations,
                                                      plain.opacity_logits, plain.sh_dc, plain.sh_rest),
                               rotation)  # without the capture's own extra properties
        keep = inside_box(upright.means.astype(np.float64), obj.fit_box_up)
        if max_gaussians is not None and len(keep) > max_gaussians:
            keep = np.sort(rng.choice(keep, max_gaussians, replace=False))
        if len(keep) == 0:
            continue
        out = upright.subset(keep)
        out.set_materials(*labels_inside_table(annotate_cloud(out, checkpoint, device, up="z").get_materials(),
                                               extremes))
        out.set("part_id", np.zeros(len(out)), np.int32)
        objects.append(out)
    return objects


def labels_inside_table(materials: tuple[np.ndarray, ...],
                        extremes: dict[str, tuple[float, float]]) -> tuple[np.ndarray, ...]:
    """The teacher's `materials` (id, E Pa, ν, ρ kg/m³) with E, ν, ρ clipped to the class table's `extremes`
    (`labels.table_extremes`).
    Why: a teacher's outputs are clamped to *its* stored label ranges, which are widened outwards at the 4th
    decimal; a pool labelled at that edge (r59 reads 117 guitar Gaussians at 10^10.9032 Pa, the table's top is
    8e10 = 10^10.90309) would carry the widening into every student's ranges, one generation after another."""
    material_id, E_pa, nu, density_kg_m3 = materials
    return (material_id, np.clip(E_pa, *extremes["E"]).astype(np.float32),
            np.clip(nu, *extremes["nu"]).astype(np.float32),
            np.clip(density_kg_m3, *extremes["density"]).astype(np.float32))


def teacher_majority(entries: list[dict]) -> dict[str, int]:
    """How many pool objects the teacher reads mostly as each material class. Why: a pool read as one class
    teaches that class for everything that looks like it (r65: an all-elastic pool pulled the converted-mesh
    WaterBottle off metal; docs/model_card.md), so the mix is written into the index and printed."""
    return dict(Counter(e["teacher_class"] for e in entries).most_common())


def make_pool(out_dir: str | Path, sources: list[str | Path], checkpoint: str | None = None, device: str = "cpu",
              max_gaussians: int | None = None, seed: int = 0) -> dict:
    """Write OUT_DIR/train (objects, label records, index.json) from `sources`; returns the index.

    The split is built beside its place and moved in whole, so a source that fails (unreadable, or no object
    after preparation: InputError naming it) leaves nothing behind; an OUT_DIR that holds a pool is refused."""
    from ..progress import progress
    from ..splat import read_splat_valid

    final = Path(out_dir) / POOL_SPLIT
    if final.exists():
        raise InputError("already holds a teacher pool (remove it first)", final)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    staging = StagedDirectory(final)  # built beside its place and moved in whole
    try:
        entries = []
        for k, source in enumerate(progress(sources, "teacher pool", total=len(sources), unit="asset")):
            objects = labelled_objects(read_splat_valid(source), checkpoint, device, max_gaussians, seed + k)
            if not objects:
                raise InputError("holds no object after preparation", source)
            for j, obj in enumerate(objects):
                stem = f"{len(entries):06d}_{POOL_CLASS}"
                obj.write(staging.path / f"{stem}.ply")
                ids, counts = np.unique(obj.get("material_id"), return_counts=True)
                record = {"index": len(entries), "file": f"{stem}.ply", "class": POOL_CLASS, "source": str(source),
                          "object": j, "gaussians": len(obj), "teacher": str(checkpoint or "shipped default"),
                          "parts": [{"name": "teacher", "part_id": 0}],
                          "teacher_class_counts": {str(c): int(n) for c, n in zip(ids, counts)}}
                (staging.path / f"{stem}.json").write_text(json.dumps(record, indent=1) + "\n")
                entries.append({"index": record["index"], "class": POOL_CLASS, "file": record["file"],
                                "gaussians": len(obj), "parts": ["teacher"], "source": Path(source).name,
                                "teacher_class": MATERIAL_NAMES.get(int(ids[np.argmax(counts)]), "unknown")})
        index = {"format_version": 1, "split": POOL_SPLIT, "count": len(entries), "classes": [POOL_CLASS],
                 "class_counts": {POOL_CLASS: len(entries)}, "teacher": str(checkpoint or "shipped default"),
                 "teacher_majority": teacher_majority(entries), "objects": entries}
        (staging.path / INDEX_NAME).write_text(json.dumps(index, indent=1) + "\n")
        staging.commit()
    except BaseException:
        staging.abort()
        raise
    return index


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pixie_gs.dataset.teacher_pool",
                                     description="label real splats/scans with a teacher into OUT_DIR/train")
    parser.add_argument("out_dir")
    parser.add_argument("sources", nargs="+", help="splat files (any format pixie reads)")
    parser.add_argument("--checkpoint", default=None, help="the teacher (default: the shipped checkpoint)")
    parser.add_argument("--max-gaussians", type=int, default=None,
                        help="thin each object at random to at most this many Gaussians (default: keep all; thinning "
                        "changes the teacher's reading and serves only to make a pool small enough to carry)")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    try:
        if args.max_gaussians is not None and args.max_gaussians < 1:
            raise InputError(f"--max-gaussians must be at least 1 (got {args.max_gaussians})")
        index = make_pool(args.out_dir, args.sources, args.checkpoint, args.device, args.max_gaussians)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    mix = ", ".join(f"{name} {n}" for name, n in index["teacher_majority"].items())
    print(f"teacher pool: {index['count']} objects from {len(args.sources)} sources in {args.out_dir}; "
          f"the teacher reads them mostly as {mix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
