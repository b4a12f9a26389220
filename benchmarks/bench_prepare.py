"""Scene preparation figures: up error on generated objects under random rotations, up and object
box on the real assets in ../shared/real, and prepare time on a 1,000,000-Gaussian capture with
the time to read that file as the same-run baseline.

usage: python benchmarks/bench_prepare.py [--objects 100] [--gaussians 20000] [--real ../shared/real] [--skip-speed]
       [--verbose]
       [--pictures docs/real --annotated DIR]   (DIR: `pixie annotate` outputs named per expectations.json)
Real meshes are converted first with `pixie convert MESH OUT.ply` (defaults), as expectations.json says.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))  # tests/upright_match.py


def generated_up_errors(count: int, n_gaussians: int = 20000) -> list[dict]:
    """Per TEST-seed object (classes round-robin, a random rotation each): class, raw up error (°),
    symmetry-aware error (tests/upright_match.py: 0 when the object put upright by the estimate is
    the same shape as put upright by the truth), whether it was counted so, the error up to the
    generator's equal-law turns (upright_match.law_error: a stack of books upside down, a frame
    turned a quarter in its plane) and whether one was used, method, confidence."""
    from scipy.spatial.transform import Rotation

    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.prepare import prepare_cloud
    from upright_match import angle_deg, equal_law_ups, law_error, symmetric_error

    table = load_class_table()
    names = sorted(table)
    out = []
    for i in range(count):
        name = names[i % len(names)]
        cloud, record = build_object(table[name], object_seed(11, "test", i), n_gaussians)
        R = Rotation.random(random_state=i).as_matrix()
        cloud.means = (cloud.means.astype(np.float64) @ R.T).astype(np.float32)
        cloud.set_covariances(R @ cloud.covariances() @ R.T)
        _, scene = prepare_cloud(cloud)
        truth = R @ [0, 0, 1]
        sym, counted = symmetric_error(cloud.means, cloud.get("part_id"), np.asarray(scene.up), truth)
        law, turned = law_error(cloud.means, cloud.get("part_id"), np.asarray(scene.up), truth,
                                equal_law_ups(record, R))
        out.append({"class": name, "raw": angle_deg(scene.up, truth), "sym": sym, "symmetric": counted,
                    "law": law, "equal_law": turned,
                    "method": scene.up_method, "confidence": scene.up_confidence, "index": i})
    return out


def real_assets(real: Path, work: Path) -> list[dict]:
    from pixie_gs.prepare import prepare_cloud
    from pixie_gs.prepare.updir import angle_deg
    from pixie_gs.splat import read_splat

    entries = json.loads((real / "expectations.json").read_text())
    rows = []
    for e in entries:
        path = asset_path(real, work, e)
        cloud = read_splat(path)
        _, scene = prepare_cloud(cloud)
        box = np.asarray(scene.objects[0].box_file) if scene.objects else None
        exp = np.asarray(e["object_box"])
        size = float((exp[1] - exp[0]).max())
        shape_only = None
        if scene.up_source == "file":  # the same mesh with its declared up hidden: the shape alone
            bare = cloud.copy()
            bare.comments = []
            shape_only = angle_deg(prepare_cloud(bare)[1].up, e["up"])
        rows.append({"file": e["file"], "up_error_deg": angle_deg(scene.up, e["up"]), "method": scene.up_method,
                     "confidence": scene.up_confidence, "shape_only_deg": shape_only,
                     "box_error_of_size": None if box is None else float(np.abs(box - exp).max() / size),
                     "counts": scene.counts, "seconds": scene.seconds})
    return rows


def speed(real: Path, work: Path) -> tuple[float, float, int]:
    """(prepare seconds, read seconds, count) on 1,000,000 Gaussians: the donut capture repeated
    with 0.5 mm jitter, written as an INRIA PLY; the module imports are warmed first."""
    from pixie_gs.prepare import prepare_cloud
    from pixie_gs.splat import SplatCloud, read_splat, write_splat

    base = read_splat(real / "orig" / "donut_fused.ply")
    reps = int(np.ceil(1_000_000 / len(base)))
    rng = np.random.default_rng(0)
    parts = []
    for k in range(reps):
        c = base.copy()
        c.means = (c.means + rng.normal(0, 5e-4, c.means.shape)).astype(np.float32)
        parts.append(c)
    big = SplatCloud.concatenate(parts).subset(np.arange(1_000_000))
    path = work / "big.ply"
    write_splat(big, path)
    t = time.perf_counter()
    cloud = read_splat(path)
    read_s = time.perf_counter() - t
    prepare_cloud(cloud.subset(np.arange(2000)))  # warm the imports (scipy) so they are not timed
    t = time.perf_counter()
    prepare_cloud(cloud)
    prep_s = time.perf_counter() - t
    return prep_s, read_s, len(cloud)


ROLE_RGB = np.array([[0.95, 0.55, 0.1], [0.6, 0.6, 0.65], [0.35, 0.6, 0.3], [0.9, 0.1, 0.1]], np.float32)


def asset_path(real: Path, work: Path, entry: dict) -> Path:
    """The splat of one expectations.json entry: meshes converted with `pixie convert` defaults."""
    stem = Path(entry["file"]).stem
    mesh = real / "orig" / f"{stem}.glb"
    if mesh.exists():
        path = work / entry["file"]
        if not path.exists():
            subprocess.run([sys.executable, "-m", "pixie_gs", "convert", "-q", str(mesh), str(path)], check=True)
        return path
    cands = [real / "orig" / entry["file"], real / "orig" / f"{stem}.compressed.ply"]
    return next(p for p in cands if p.exists())


def pictures(real: Path, work: Path, out_dir: Path, annotated: Path | None, size: int = 240) -> None:
    """docs/real/prepare_<asset>.png: raw (the file's +z up) | seen with the estimated up | coloured
    by role (orange object, grey background, green ground, red floater) | annotated material class and
    log10 E (viridis over the dataset's range, from `annotated`/<file>), seen with the same up, framed
    on the object."""
    from pixie_gs.gsrender import Gaussians, orbit_cameras, render_many, render_modes, to_uint8
    from pixie_gs.prepare import ROLE_OBJECT, prepare_cloud
    from pixie_gs.render import contact_sheet, save_png
    from pixie_gs.splat import read_splat
    from pixie_gs.viz import log_e_colors, material_colors

    for e in json.loads((real / "expectations.json").read_text()):
        stem = Path(e["file"]).stem
        cloud = read_splat(asset_path(real, work, e))
        prepared, scene = prepare_cloud(cloud)
        role = prepared.get("role")
        obj = cloud.means[role == ROLE_OBJECT] if (role == ROLE_OBJECT).any() else cloud.means
        g = Gaussians.from_cloud(cloud, "cpu")
        cam_raw = orbit_cameras(cloud.means, 1, size, size, up="z", elevation_deg=20.0)[0]
        cam_up = orbit_cameras(obj, 1, size, size, up=np.asarray(scene.up), elevation_deg=20.0)[0]
        images = [render_modes(cloud, cam_raw, ["colour"], gaussians=g)[0]]
        labels = [f"{stem}: raw, file z up"]
        colour_up, roles = render_many(g, cam_up, [None, ROLE_RGB[role]])
        up = ",".join(f"{round(v, 2) + 0.0:.2f}" for v in scene.up)
        images += [to_uint8(colour_up), to_uint8(roles)]
        labels += [f"prepared: up {up}", "role: object/backgr./ground/floater"]
        ann = annotated / e["file"] if annotated is not None else None
        if ann is not None and ann.exists():
            a = read_splat(ann)
            mid, E_pa, _, _ = a.get_materials()
            images += [to_uint8(im) for im in render_many(g, cam_up, [material_colors(mid), log_e_colors(E_pa)])]
            labels += ["annotated: material", f"log10 E (median {np.median(E_pa):.2g} Pa)"]
        save_png(contact_sheet(images, labels, columns=len(images)), out_dir / f"prepare_{stem}.png")
        print(f"wrote {out_dir / f'prepare_{stem}.png'}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--objects", type=int, default=100)
    ap.add_argument("--real", default="../shared/real")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--gaussians", type=int, default=20000, help="Gaussians per generated object")
    ap.add_argument("--verbose", action="store_true", help="one line per generated object")
    ap.add_argument("--pictures", default=None, help="write prepare_<asset>.png here (and do nothing else)")
    ap.add_argument("--annotated", default=None, help="folder of annotated real assets for the pictures")
    args = ap.parse_args()
    real = Path(args.real)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.pictures:
            pictures(real, work, Path(args.pictures), Path(args.annotated) if args.annotated else None)
            return 0
        if not args.skip_speed and real.exists():
            prep_s, read_s, n = speed(real, work)
            print(f"speed: prepare {n} Gaussians {prep_s:.2f} s; read the same file {read_s:.2f} s "
                  f"(ratio {prep_s / read_s:.2f}); target ≤ 3 s")
        if real.exists():
            rows = real_assets(real, work)
            for row in rows:
                box = "none" if row["box_error_of_size"] is None else f"{row['box_error_of_size']:.2f}"
                print(f"real {row['file']:16s} up error {row['up_error_deg']:6.1f}° ({row['method']}, "
                      f"confidence {row['confidence']:.2f}); object box error {box} of its size; "
                      f"{row['seconds']:.2f} s"
                      + ("" if row["shape_only_deg"] is None else
                         f"; declared up hidden, from the shape alone: {row['shape_only_deg']:.1f}°"))
            ok = sum(r["up_error_deg"] <= 10.0 for r in rows)
            print(f"real: up within 10° on {ok} of {len(rows)} assets")
    if args.objects:
        rows = generated_up_errors(args.objects, args.gaussians)
        for key, label in (("raw", "raw"), ("sym", "symmetry-aware"), ("law", "symmetry-aware, equal-law turns")):
            e = np.array([r[key] for r in rows])
            print(f"generated ({label}): {len(e)} TEST-seed objects at {args.gaussians} Gaussians, up error median "
                  f"{np.median(e):.1f}°, worst {e.max():.1f}°, ≤ 20° on {np.mean(e <= 20) * 100:.0f} %, "
                  f"≤ 5° on {np.mean(e <= 5) * 100:.0f} %; target median ≤ 5°, worst ≤ 20°")
        sym = [r for r in rows if r["symmetric"]]
        print(f"  counted as symmetric equivalents (error 0): {len(sym)}: "
              + ", ".join(f"{r['class']}#{r['index']} (raw {r['raw']:.0f}°)" for r in sym))
        law = [r for r in rows if r["equal_law"]]
        print(f"  counted at an equal-law turn of the truth (the generator's law unchanged by it): {len(law)}: "
              + ", ".join(f"{r['class']}#{r['index']} (symmetry-aware {r['sym']:.0f}°)" for r in law))
        for name in sorted({r["class"] for r in rows}):
            v = np.array([r["raw"] for r in rows if r["class"] == name])
            w = np.array([r["sym"] for r in rows if r["class"] == name])
            q = np.array([r["law"] for r in rows if r["class"] == name])
            print(f"  {name:18s} raw median {np.median(v):6.1f}° worst {v.max():6.1f}° | "
                  f"symmetry-aware median {np.median(w):6.1f}° worst {w.max():6.1f}° | equal-law worst {q.max():6.1f}°")
        if args.verbose:
            for r in rows:
                print(f"  #{r['index']:3d} {r['class']:18s} raw {r['raw']:6.1f}° sym {r['sym']:6.1f}° law {r['law']:6.1f}° "
                      f"conf {r['confidence']:.2f} {r['method']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
