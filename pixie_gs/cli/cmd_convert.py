"""`pixie convert IN OUT`: a triangle mesh to a 3DGS splat, or a splat from one format to another.

Mesh input (.glb/.gltf/.obj/.ply/.stl/.off) is sampled into Gaussians; splat input in any format
pixie-gs reads (found by content) is rewritten in the format OUT's name asks for (.ply INRIA 3DGS,
.compressed.ply SuperSplat, .splat, .spz) or `--format`; lossy targets say what they lose.
"""
from __future__ import annotations

import argparse
from .options import add_drop_invalid_option

SPLAT_ONLY_SUFFIXES = (".splat", ".spz")


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "convert", parents=parents, help="mesh to splat, or splat between formats (.ply .compressed.ply .splat .spz)",
        description="With a splat as IN (any format pixie-gs reads: INRIA 3DGS .ply, SuperSplat compressed "
        ".ply, .splat, .spz; found by content), rewrite it in OUT's format: .compressed.ply → SuperSplat "
        "compressed PLY, .splat → antimatter15, .spz → Niantic, otherwise INRIA 3DGS .ply (or --format). "
        "With a triangle mesh as IN, sample it into flat surface Gaussians coloured from its texture, "
        "vertex or face colours (and, with --fill, isotropic Gaussians inside a closed mesh); scenes are "
        "flattened with their transforms; the same --seed gives identical bytes.",
        epilog="example: pixie convert scene.spz scene.ply  (also: pixie convert out.ply out.compressed.ply; "
        "pixie convert duck.glb duck.ply --count 200000 --fill --seed 1)",
    )
    p.add_argument("mesh", metavar="IN", help="splat (.ply .compressed.ply .splat .spz) or mesh "
                   "(.glb .gltf .obj .ply .stl .off)")
    p.add_argument("out", metavar="OUT", help="splat file to write; its name picks the format (see --format)")
    p.add_argument("--format", default=None, choices=["ply", "compressed", "splat", "spz"],
                   help="output format, whatever OUT's name: ply (INRIA 3DGS), compressed (SuperSplat), "
                   "splat (antimatter15), spz (Niantic)")
    p.add_argument("--count", type=int, default=None, help="mesh input: surface Gaussians (default 100000)")
    p.add_argument("--fill", action="store_true", help="mesh input: also fill the inside of a watertight mesh")
    p.add_argument("--fill-count", type=int, default=None,
                   help="mesh input: interior Gaussians with --fill (default: same as --count)")
    p.add_argument("--seed", type=int, default=0, help="mesh input: random seed (default 0)")
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file")
    add_drop_invalid_option(p, prefix="splat input: ")
    p.add_argument("--preview", metavar="PNG", default=None,
                   help="also write a PNG with four views of the splat (point-splat render; +y up "
                   "for glTF/OBJ input, whose convention it is, +z up otherwise)")
    p.set_defaults(func=run)
    return p


def _splat_format_of(path: str) -> str | None:
    """The splat format of IN, None when IN is not a splat (then it is read as a mesh)."""
    from pathlib import Path

    from ..errors import InputError
    from ..formats import detect_format

    try:
        return detect_format(path)
    except InputError:
        if Path(path).suffix.lower() in SPLAT_ONLY_SUFFIXES:
            raise
        return None


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..atomic import check_distinct_output
    from ..errors import InputError

    for target in [args.out] + ([args.preview] if args.preview else []):
        if not Path(target).parent.is_dir():
            raise InputError("output directory does not exist", Path(target).parent)
    check_distinct_output(args.mesh, args.out, args.force)
    source_format = _splat_format_of(args.mesh)
    if source_format is not None:
        cloud = convert_splat(args, source_format)
        up = "z"
    else:
        cloud = convert_mesh(args)
        up = "y" if Path(args.mesh).suffix.lower() in (".glb", ".gltf", ".obj") else "z"
    if args.preview:
        from ..progress import stage

        write_preview(cloud, args.preview, up)
        stage(f"wrote preview {args.preview}")
    return 0


def convert_splat(args: argparse.Namespace, source_format: str):
    """Rewrite the splat IN in OUT's format, saying what a lossy target drops."""
    from ..errors import InputError
    from ..formats import LABELS, format_for_path, normalise_format
    from ..progress import stage
    from ..splat import read_splat_valid

    if args.count is not None or args.fill or args.fill_count is not None:
        raise InputError("--count/--fill/--fill-count apply to mesh input; IN is a splat "
                         f"({LABELS[source_format]})", args.mesh)
    target = normalise_format(args.format) if args.format else format_for_path(args.out)
    cloud = read_splat_valid(args.mesh, args.drop_invalid)
    stage(f"read {len(cloud)} Gaussians ({LABELS[source_format]}, SH degree {cloud.sh_degree}) from {args.mesh}")
    write_converted(cloud, args.out, target)
    return cloud


GLTF_UP_COMMENT = "pixie up 0 1 0"


def convert_mesh(args: argparse.Namespace):
    """Sample the mesh IN into a splat written to OUT (format by OUT's name or --format)."""
    from pathlib import Path

    import numpy as np

    from ..convert import load_mesh, mesh_to_splat
    from ..errors import InputError
    from ..formats import format_for_path, normalise_format
    from ..progress import stage

    count = 100_000 if args.count is None else args.count
    if count < 1:
        raise InputError(f"--count must be ≥ 1 (got {count})")
    if args.fill_count is not None and args.fill_count < 0:
        raise InputError(f"--fill-count must be ≥ 0 (got {args.fill_count})")
    target = normalise_format(args.format) if args.format else format_for_path(args.out)
    mesh = load_mesh(args.mesh)
    stage(f"read {len(mesh.faces)} triangles from {args.mesh}; sampling {count} surface Gaussians"
          + (" and filling the interior" if args.fill else ""))
    cloud = mesh_to_splat(mesh, count, np.random.default_rng(args.seed), fill=args.fill, n_fill=args.fill_count)
    if Path(args.mesh).suffix.lower() in (".glb", ".gltf"):
        cloud.comments.append(GLTF_UP_COMMENT)  # the glTF spec defines +Y as up; pixie prepare honours it
    write_converted(cloud, args.out, target)
    return cloud


def write_preview(cloud, png: str, up: str = "z") -> None:
    """Four views (azimuth 0/90/180/270°, elevation 20°) of the splat's colours in one PNG."""
    from ..render import contact_sheet, render_points, save_png

    bounds = cloud.bounds()
    azimuths = (0, 90, 180, 270)
    views = [render_points(cloud.means, cloud.rgb(), azimuth_deg=az, up=up, bounds=bounds) for az in azimuths]
    save_png(contact_sheet(views, [f"azimuth {az} deg" for az in azimuths], columns=4), png)


def write_converted(cloud, out, target: str) -> None:
    """Write `cloud` to `out` in format `target`, saying first what a lossy format drops."""
    from ..formats import LABELS, lossy_note, write_any
    from ..progress import stage

    note = lossy_note(cloud, target)
    if note:
        stage(f"lossy: {note}")
    write_any(cloud, out, target)
    stage(f"wrote {len(cloud)} Gaussians to {out} ({LABELS[target]})")

