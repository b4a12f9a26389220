"""`pixie render IN.ply|FRAMES_DIR --out FILE.mp4|.gif|.png`: real 3D Gaussian splat pictures."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..devices import DEVICE_CHOICES, DEVICE_HELP
from ..errors import InputError
from .options import add_drop_invalid_option

MODE_CHOICES = ("colour", "material", "logE", "confidence")
BACKGROUNDS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}
FPS_RANGE = (0.1, 120.0)


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "render", parents=parents, help="render a splat or a simulation's frames as a splat viewer shows them",
        description="Render 3D Gaussian splats for real (EWA-projected ellipses, view-dependent SH colour, "
        "depth-sorted alpha compositing, as 3DGS viewers do). IN is a splat file (any format `pixie info` "
        "reads) or a directory of frame_*.ply from `pixie simulate`. Each picture shows the chosen modes side "
        "by side: colour (the splat's own colour), material (predicted class), logE (log10 Young's modulus), "
        "confidence (if the file has it). A file is orbited (or drawn once for .png); frames are drawn from a "
        "still camera that frames the whole run (a .png shows a strip of evenly spaced frames).",
        epilog="example: pixie render annotated.ply --out orbit.mp4 --up y   (also: pixie render frames/ --out "
        "run.gif --modes colour,material; pixie render scene.ply --camera cameras.json --out view.png)",
    )
    p.add_argument("input", metavar="IN", help="splat file, or a directory of frame_*.ply")
    p.add_argument("--out", required=True, metavar="FILE", help="output .mp4, .gif or .png")
    p.add_argument("--modes", metavar="LIST", help="comma-separated modes from " + ", ".join(MODE_CHOICES)
                   + " (default: every mode the file has attributes for)")
    p.add_argument("--camera", default="auto", metavar="orbit|fixed|FILE",
                   help="orbit (circle the object), fixed (one still view), or an INRIA cameras.json / "
                   "nerfstudio transforms.json (every camera in turn; frames: --camera-index). Default: orbit "
                   "for an animated file output, fixed otherwise")
    p.add_argument("--camera-index", type=int, metavar="K",
                   help="with a cameras file: only camera K (0-based); frames always use one camera (default 0)")
    p.add_argument("--size", type=int, default=320, metavar="PX", help="height of each view in px (320)")
    p.add_argument("--frames", type=int, default=60, metavar="N", help="orbit: views around the object (60)")
    p.add_argument("--fps", type=float, default=15.0, metavar="F", help="animation frames per second (15)")
    from ..prepare.updir import add_up_option

    add_up_option(p, default="z")
    p.add_argument("--crop", metavar="SPEC", help="draw only the Gaussians inside box:x0,y0,z0,x1,y1,z1 or "
                   "sphere:cx,cy,cz,r (file coordinates; for scene captures, to show one object)")
    p.add_argument("--elevation", type=float, default=20.0, metavar="DEG", help="camera elevation (20°)")
    p.add_argument("--azimuth", type=float, default=-90.0, metavar="DEG",
                   help="camera azimuth around the up axis; the orbit starts here (−90°: looking along +y for z up)")
    p.add_argument("--background", choices=tuple(BACKGROUNDS), default="white", help="background (white)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help=DEVICE_HELP)
    add_drop_invalid_option(p)
    p.set_defaults(func=run)
    return p


def parse_modes(text: str | None) -> list[str] | None:
    if text is None:
        return None
    modes = [m.strip() for m in text.split(",") if m.strip()]
    for m in modes:
        if m not in MODE_CHOICES:
            raise InputError(f"unknown mode '{m}' in --modes (choose from {', '.join(MODE_CHOICES)})")
    if not modes:
        raise InputError("--modes is empty")
    return modes


def parse_region(text: str | None):
    """A box or sphere crop (prepare's --crop syntax); a point crop selects a cluster, not a region."""
    from ..prepare.objects import parse_crop

    crop = parse_crop(text)
    if crop is not None and crop.kind == "point":
        raise InputError("--crop for render must be a box: or sphere: region")
    return crop


def run(args: argparse.Namespace) -> int:
    from ..devices import resolve_torch_device
    from ..gsrender.camera import orbit_cameras, read_cameras
    from ..gsrender.sequence import (check_sizes, render_frames_dir, render_splat_file, sheet, strip_sheet)
    from ..gsrender.video import output_format, save_frames
    from ..progress import stage
    from ..splat import read_splat_valid

    source, out = Path(args.input), Path(args.out)
    kind = output_format(out)
    modes = parse_modes(args.modes)
    check_sizes(args.size, args.size)
    if not FPS_RANGE[0] <= args.fps <= FPS_RANGE[1]:
        raise InputError(f"--fps must be within {FPS_RANGE[0]:g}..{FPS_RANGE[1]:g}, got {args.fps:g}")
    if not 1 <= args.frames <= 10_000:
        raise InputError(f"--frames must be 1..10000, got {args.frames}")
    if not source.exists():
        raise InputError("no such file or directory", source)
    if out.exists() and out.resolve() == source.resolve():
        raise InputError("output is the input; refusing to overwrite it", out)
    if not out.parent.resolve().is_dir():
        raise InputError("output directory does not exist", out.parent)
    from ..prepare.updir import parse_up

    up = parse_up(args.up)
    if up is None:
        raise InputError("--up auto is not available for render; give an axis (z, y, -y, …) or a vector")
    crop = parse_region(args.crop)
    device = resolve_torch_device(args.device)
    background = BACKGROUNDS[args.background]
    cameras = None
    if args.camera not in ("auto", "orbit", "fixed"):
        cameras = read_cameras(args.camera)
        if args.camera_index is not None:
            if not 0 <= args.camera_index < len(cameras):
                raise InputError(f"--camera-index {args.camera_index} is out of range (0..{len(cameras) - 1})",
                                 args.camera)
            cameras = [cameras[args.camera_index]]
        cameras = [c.resized(max(8, round(c.width * args.size / c.height)), args.size) for c in cameras]
    elif args.camera_index is not None:
        raise InputError("--camera-index needs --camera FILE")

    if source.is_dir():
        if args.camera == "orbit":
            raise InputError("frames are drawn from a still camera; use --camera fixed or a cameras file")
        if crop is not None:
            raise InputError("--crop applies to a splat file, not to a frames directory")
        stage(f"rendering the frames of {source}")
        views, modes, labels = render_frames_dir(source, modes, args.size, args.fps, up, args.azimuth,
                                                 args.elevation, device, background,
                                                 camera=cameras[0] if cameras else None)
        if kind == ".png":
            frames = [strip_sheet(views, modes, labels)]
        else:
            frames = [sheet(v, modes, lab) for v, lab in zip(views, labels)]
    else:
        cloud = read_splat_valid(source, args.drop_invalid)
        if crop is not None:
            inside = crop.contains(cloud.means.astype(np.float64))
            if not inside.any():
                raise InputError(f"--crop {args.crop} holds none of its {len(cloud)} Gaussians", source)
            cloud = cloud.subset(np.flatnonzero(inside))
        if cameras is None:
            count = args.frames if (args.camera == "orbit" or (args.camera == "auto" and kind != ".png")) else 1
            cameras = orbit_cameras(cloud.means, count, args.size, args.size, up=up,
                                    elevation_deg=args.elevation, azimuth0_deg=args.azimuth)
        elif kind == ".png":
            cameras = cameras[:1]
        stage(f"rendering {len(cloud)} Gaussians from {len(cameras)} view(s)")
        views, modes, labels = render_splat_file(cloud, modes, cameras, device, background)
        frames = [sheet(v, modes, lab) for v, lab in zip(views, labels)]
        if kind == ".png" and len(frames) > 1:
            frames = [strip_sheet(views, modes, labels)]
    save_frames(frames, out, fps=args.fps)
    h, w = frames[0].shape[:2]
    stage(f"wrote {out} ({len(frames)} frame(s) of {w}×{h} px; modes {', '.join(modes)})")
    print(out)
    return 0
