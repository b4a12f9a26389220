"""`pixie simulate IN.ply --out DIR`: move an annotated splat with the Warp MPM, write frames."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..devices import DEVICE_CHOICES, DEVICE_HELP
from .cmd_prepare import add_prepare_options
from ..errors import InputError
from .options import add_drop_invalid_option

PRESET_CHOICES = ("drop", "wind", "push")
FPS_RANGE = (1e-3, 1e5)  # output frames per second: beyond, frame times overflow or vanish


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "simulate", parents=parents, help="simulate an annotated splat (MPM) and write per-frame .ply files",
        description="Simulate an annotated 3DGS splat (material_id, E, nu, density per Gaussian, as written "
        "by `pixie annotate`) with an MLS-MPM in NVIDIA Warp. Writes DIR/frame_00000.ply ... (valid 3DGS files "
        "keeping every input property; positions moved and covariances advanced as F Σ Fᵀ, in the input's "
        "coordinates), DIR/tracks.npz (t (T,) s, x (T,N,3)) and DIR/preview.png (a strip of frames). "
        "Frame 0 is the initial state.",
        epilog="example: pixie simulate annotated.ply --out frames/ --preset drop --frames 48 --fps 24 --rrd sim.rrd",
    )
    p.add_argument("input", metavar="IN.ply", help="annotated 3D Gaussian splat")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    scene = p.add_mutually_exclusive_group()
    scene.add_argument("--scene", metavar="FILE", help="scene JSON (see docs/scene.md)")
    scene.add_argument("--preset", choices=PRESET_CHOICES, help="a shipped scene (default: drop)")
    p.add_argument("--frames", type=int, default=48, metavar="N", help="number of output frames incl. frame 0 (48)")
    p.add_argument("--fps", type=float, default=24.0, metavar="F", help="output frames per second (24)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help=DEVICE_HELP)
    p.add_argument("--rrd", metavar="FILE", help="save a rerun recording of the run")
    p.add_argument("--render", metavar="FILE", help="also render the frames as real splats (colour | material | "
                   "log E) to FILE.gif / .mp4 / .png, as `pixie render DIR --out FILE` does")
    p.add_argument("--spawn", action="store_true", help="stream the run live to a rerun viewer")
    p.add_argument("--fill", action="store_true", help="fill the enclosed interior of solid objects with particles "
                   "(default: automatic for a prepared object that is a closed surface shell)")
    p.add_argument("--per-cell", type=int, metavar="N", help="simulate at most N Gaussians per grid cell and "
                   "move the others with their nearest simulated one of the same material (frames still hold "
                   "every Gaussian); much faster on dense captures. Default: simulate all")
    add_prepare_options(p)
    p.add_argument("--force", action="store_true", help="overwrite earlier frames in DIR")
    add_drop_invalid_option(p)
    p.set_defaults(func=run)
    return p


def load_scene(args: argparse.Namespace):
    """The scene asked for on the command line (default: the `drop` preset)."""
    from ..sim.scene import Scene

    if args.scene:
        return Scene.from_json(args.scene)
    return Scene.preset(args.preset or "drop")


def run(args: argparse.Namespace) -> int:
    from .. import viz
    from ..atomic import check_distinct_output
    from ..progress import stage
    from ..limits import require_disk
    from ..sim.frames import FrameWriter, check_output_dir, estimate_output_bytes
    from ..sim.run import FrameState, material_arrays, placement_transform, simulate
    from ..splat import read_splat_valid

    if args.render:
        from ..gsrender.video import output_format

        from ..gsrender.video import ffmpeg_exe

        # a bad suffix, or .mp4 without an ffmpeg, stops before any work
        if output_format(args.render) == ".mp4" and ffmpeg_exe() is None:
            raise InputError("writing .mp4 needs ffmpeg: `pip install imageio-ffmpeg`, or use .gif", args.render)
    if args.frames < 1:
        raise InputError(f"--frames must be ≥ 1, got {args.frames}")
    if not FPS_RANGE[0] <= args.fps <= FPS_RANGE[1]:
        raise InputError(f"--fps must be within {FPS_RANGE[0]:g}..{FPS_RANGE[1]:g} frames per second, got {args.fps:g}")
    if args.per_cell is not None and args.per_cell < 1:
        raise InputError(f"--per-cell must be ≥ 1, got {args.per_cell}")
    cloud = read_splat_valid(args.input, args.drop_invalid)
    material_arrays(cloud)  # one-line error before anything is created
    scene = load_scene(args)
    prepared_cloud, prepared = _prepare(cloud, args, scene)
    if args.rrd:
        check_distinct_output(args.input, args.rrd, force=False)
        if Path(args.rrd).resolve().parent == Path(args.out).resolve():
            raise InputError("put the --rrd file outside the --out directory", args.rrd)
    check_output_dir(args.out, args.force, inputs=(args.input, args.scene))
    require_disk(estimate_output_bytes(cloud, args.frames), f"{args.frames} frames of {len(cloud)} Gaussians",
                 Path(args.out).resolve().parent)
    writer = FrameWriter(args.out, cloud, force=args.force, frames=args.frames, inputs=(args.input, args.scene))
    try:
        rec = viz.open_recording("pixie-simulate", rrd_path=args.rrd, spawn=args.spawn)
    except BaseException:
        writer.abort()
        raise
    if prepared is not None:
        from ..sim.prepared import place_prepared

        tf = place_prepared(prepared_cloud, prepared, scene).transform
    else:
        tf = placement_transform(cloud.means, scene)
    entities = viz.MATERIAL_VIEW_ENTITIES

    def on_frame(state: FrameState) -> None:
        writer.write(state)
        if state.index == 0:
            _log_world(rec, scene)
            viz.log_material_views(rec, cloud, time_s=0.0, means=state.x_world,
                                   radii=viz.splat_radii(cloud, scale=tf.scale))
        else:
            viz.log_positions(rec, entities, state.x_world, time_s=state.time_s)

    stage(f"simulating {len(cloud)} Gaussians of {args.input}: {args.frames} frames at {args.fps:g} fps")
    try:
        if prepared is not None:
            from ..sim.prepared import simulate_prepared

            traj = simulate_prepared(prepared_cloud, prepared, scene, args.frames, args.fps, device=args.device,
                                     on_frame=on_frame, fill=True if args.fill else None,
                                     positions_out=writer.positions, per_cell=args.per_cell)
        elif args.per_cell is not None:
            from ..sim.subsample import simulate_per_cell

            traj = simulate_per_cell(cloud, scene, args.frames, args.fps, args.per_cell, device=args.device,
                                     on_frame=on_frame, fill=args.fill, positions_out=writer.positions)
        else:
            traj = simulate(cloud, scene, args.frames, args.fps, device=args.device, on_frame=on_frame,
                            fill=args.fill, positions_out=writer.positions)
        preview = writer.write_preview(traj.t, traj.x, scene.up if prepared is None else prepared.nearest_axis)
        viz.send_layout(rec, fps=args.fps, shared=["world"])
        saved = viz.close_recording(rec)
        tracks = writer.finish(traj.t, traj.x)  # last: the old output is replaced only by a complete run
    except BaseException:
        writer.abort()
        viz.discard_recording(rec)
        raise
    stage(f"wrote {args.frames} frames, {tracks.name} and {preview.name} to {args.out}"
          + (f" ({traj.simulated} of {len(cloud)} Gaussians simulated, the others carried)"
             if traj.simulated is not None else "")
          + (f" (+{traj.filled} interior particles simulated)" if traj.filled else "")
          + (f"; rerun recording {saved}" if saved else ""))
    if args.render:
        _render(args, scene.up if prepared is None else prepared.nearest_axis)
    return 0


def _render(args: argparse.Namespace, up: str) -> None:
    """Real splat renders of the frames just written (see `pixie render`)."""
    from ..devices import resolve_torch_device
    from ..gsrender.sequence import render_frames_dir, sheet, strip_sheet
    from ..gsrender.video import save_frames
    from ..progress import stage

    views, modes, labels = render_frames_dir(Path(args.out), None, 320, args.fps, up, -90.0, 20.0,
                                             resolve_torch_device(args.device), (1.0, 1.0, 1.0))
    if Path(args.render).suffix.lower() == ".png":
        pictures = [strip_sheet(views, modes, labels)]
    else:
        pictures = [sheet(v, modes, lab) for v, lab in zip(views, labels)]
    save_frames(pictures, args.render, fps=args.fps)
    stage(f"rendered {len(views)} frames ({', '.join(modes)}) to {args.render}")


def _prepare(cloud, args: argparse.Namespace, scene):
    """(cloud with roles, PreparedScene) unless --no-prepare; --up given on the command line wins
    over the scene's `up` (a scene file's `up` is used only with --no-prepare)."""
    from ..prepare import parse_crop, parse_up
    from .cmd_prepare import prepare_from_args

    given_up = parse_up(args.up)
    parse_crop(args.crop)
    if given_up is None and args.scene and scene.up != "z":
        args.up = scene.up  # the scene file names the up axis: that is a given up
        given_up = parse_up(args.up)
    if args.no_prepare:
        if given_up is not None and args.up.lstrip("+") in ("x", "y", "z", "-x", "-y", "-z"):
            scene.up = args.up.lstrip("+")
        return cloud, None
    return prepare_from_args(cloud, args)


def _log_world(rec, scene) -> None:
    """Static context for the rerun views: z-up axes, the domain box and the ground plane (m)."""
    if not rec.is_enabled():
        return
    import numpy as np
    import rerun as rr

    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    origin, size = scene.domain_origin(), scene.domain_size
    rec.log("world/domain", rr.Boxes3D(centers=[origin + size / 2], half_sizes=[size / 2],
                                       colors=[(120, 120, 120)]), static=True)
    if scene.ground.enabled:
        h = scene.ground.height_m
        corners = np.array([[origin[0], origin[1], h], [origin[0] + size[0], origin[1], h],
                            [origin[0] + size[0], origin[1] + size[1], h], [origin[0], origin[1] + size[1], h],
                            [origin[0], origin[1], h]])
        rec.log("world/ground", rr.LineStrips3D([corners], colors=[(90, 160, 90)]), static=True)
