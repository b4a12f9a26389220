"""`pixie demo`: the shipped potted tree, annotated by the shipped checkpoint, swaying in wind.

One end-to-end run of the product on a small CPU budget (< 2 minutes on a 2-core laptop CPU):

1. read the example splat pixie_gs/data/examples/tree.ply (20k Gaussians, z up);
2. `annotate_cloud` with the shipped checkpoint → DIR/tree_annotated.ply (every Gaussian);
3. keep at most `particles_per_cell` Gaussians per simulation grid cell (spatially even, so thin
   trunks and branches stay connected on the grid) → the simulated Gaussians;
4. simulate `DEMO_SCENE` (a 0.5 m tree, wind gust along +x, pot anchored) → DIR/frames/frame_*.ply
   and DIR/frames/tracks.npz, streamed to DIR/demo.rrd (RGB | material | log E views + time slider);
5. point-splat pictures a person can open without rerun: DIR/demo.gif and DIR/demo_strip.png.

Why gravity is off in the demo scene: the Pixie labels give a tree trunk an effective Young's
modulus of ~2 MPa (visual plausibility, not real wood); such a trunk cannot carry a leafy crown
under full gravity at any size the grid resolves, and the crown would slump instead of sway.
The wind alone then shows what the predicted stiffness field does: soft leaves lag and flutter,
the stiffer trunk bends, the stationary pot stays put.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError
from .progress import stage
from .splat import SplatCloud

EXAMPLE_NAMES = ("tree", "duck", "can", "sand", "snow")

# The demo's world (keys as in docs/scene.md). Wind blows along +x for 0.8 s with a gust, then
# stops, so the tree bends downwind and swings back. The pot's base (lowest 3 cm) is anchored;
# the pot itself is held by its predicted `stationary` material.
DEMO_SCENE: dict[str, Any] = {
    "up": "z",
    "object": {"size_m": 0.5, "position": [0.0, 0.0, 0.0]},
    "domain": {"size_m": 1.2, "grid": 32},
    "gravity": [0.0, 0.0, 0.0],
    "ground": {"enabled": True, "height_m": 0.0, "friction": 0.8},
    "damping": 0.5,
    "wind": [{"acceleration": [0.6, 0.0, 0.0], "start_s": 0.0, "end_s": 0.8,
              "gust_amplitude": 0.3, "gust_frequency_hz": 1.25}],
    "fixed": [{"region": {"min": [-1.0, -1.0, -0.1], "max": [1.0, 1.0, 0.03]}}],
    # caps the substeps a frame may take: parts stiffer than this allows are softened (and
    # reported), which bounds the run time whatever stiffness the model predicts
    "solver": {"max_substeps_per_frame": 600},
}


@dataclass
class DemoSettings:
    """Sizes that keep the demo under 2 minutes on a 2-core CPU (frames at `fps` frames/s)."""

    frames: int = 30
    fps: float = 15.0
    particles_per_cell: int = 6
    seed: int = 0
    device: str = "auto"
    checkpoint: str | Path | None = None  # None = the shipped checkpoint
    image_size_px: int = 280
    strip_frames: int = 6


@dataclass
class DemoResult:
    """What the demo wrote, and the measured motion (input units of the tree splat)."""

    out_dir: Path
    files: dict[str, Path]
    gaussians: int
    simulated: int
    seconds: dict[str, float] = field(default_factory=dict)
    top_displacement: np.ndarray | None = None  # (T,3) mean displacement of the top 10 % of the tree
    anchored_max_displacement: float = 0.0  # largest motion of any fixed/stationary Gaussian
    material_counts: dict[str, int] = field(default_factory=dict)


def example_path(name: str) -> Path:
    """Path of an example splat shipped in the package (pixie_gs/data/examples/NAME.ply)."""
    if name not in EXAMPLE_NAMES:
        raise InputError(f"unknown example '{name}' (choose from {', '.join(EXAMPLE_NAMES)})")
    path = Path(str(resources.files("pixie_gs") / "data" / "examples" / f"{name}.ply"))
    if not path.is_file():
        raise InputError("shipped example splat is missing; reinstall pixie-gs", path)
    return path


def subsample_per_cell(cloud: SplatCloud, scene, per_cell: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most `per_cell` Gaussians per simulation grid cell (chosen at random
    with `seed`), with the object placed as `scene` places it.

    Unlike a uniform random subset, this keeps thin parts (trunks, branches, can walls) as
    connected on the grid as the full splat is, while dense blobs are thinned: the particle
    count, and so the run time, follows the number of occupied cells.
    """
    from .sim.run import placement_transform

    if per_cell < 1:
        raise InputError(f"particles per cell must be ≥ 1, got {per_cell}")
    x = placement_transform(cloud.means, scene).to_world(cloud.means)
    cell = np.floor((x - scene.domain_origin()) / scene.dx).astype(np.int64)
    order = np.random.default_rng(seed).permutation(len(x))
    _, group = np.unique(cell[order], axis=0, return_inverse=True)
    group = group.reshape(-1)
    by_group = np.argsort(group, kind="stable")
    starts = np.concatenate([[0], np.cumsum(np.bincount(group))[:-1]])
    rank = np.empty(len(group), np.int64)
    rank[by_group] = np.arange(len(group)) - starts[group[by_group]]
    return np.sort(order[rank < per_cell])


def render_clip(x_world: np.ndarray, colours: list[np.ndarray], labels: list[str], times_s: np.ndarray,
                size_px: int, azimuth_deg: float = -90.0, elevation_deg: float = 12.0) -> list[np.ndarray]:
    """One picture per frame of positions x_world (T,N,3) (z up): the views coloured by each of
    `colours` side by side, fitted to the bounds of the whole run so the camera stays still."""
    from .render import contact_sheet, render_points

    flat = x_world.reshape(-1, 3)
    bounds = (flat.min(axis=0), flat.max(axis=0))
    pictures = []
    for i in range(len(x_world)):
        views = [render_points(x_world[i], c, size=(size_px, size_px), azimuth_deg=azimuth_deg,
                               elevation_deg=elevation_deg, up="z", bounds=bounds) for c in colours]
        pictures.append(contact_sheet(views, [f"{lab}  t = {times_s[i]:.2f} s" for lab in labels], len(views)))
    return pictures


def strip(pictures: list[np.ndarray], times_s: np.ndarray, count: int) -> np.ndarray:
    """`count` evenly spaced pictures of a clip in one row (a PNG summary of the animation)."""
    from .render import contact_sheet

    pick = np.unique(np.linspace(0, len(pictures) - 1, min(count, len(pictures))).round().astype(int))
    return contact_sheet([pictures[i] for i in pick], [f"frame {i}" for i in pick], len(pick))


def prepare_out_dir(out_dir: str | Path) -> Path:
    """The demo's output directory (created; its own earlier files are replaced on success)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a directory, but a file of that name exists", out)
    if not out.exists() and not out.parent.is_dir():
        raise InputError("parent directory does not exist", out.parent)
    out.mkdir(exist_ok=True)
    return out


def run_demo(out_dir: str | Path = "pixie_demo", settings: DemoSettings | None = None) -> DemoResult:
    """Annotate, simulate and picture the shipped potted tree; returns what was written."""
    from . import viz
    from .annotate import annotate_cloud
    from .materials import MATERIAL_NAMES, STATIONARY
    from .render import save_gif, save_png
    from .sim.frames import FrameWriter
    from .sim.run import FrameState, simulate
    from .sim.scene import Scene
    from .splat import read_splat

    s = settings or DemoSettings()
    if s.frames < 2:
        raise InputError(f"--frames must be ≥ 2 for an animation, got {s.frames}")
    out = prepare_out_dir(out_dir)
    files = {"annotated": out / "tree_annotated.ply", "frames": out / "frames", "rrd": out / "demo.rrd",
             "gif": out / "demo.gif", "strip": out / "demo_strip.png", "scene": out / "scene.json"}
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[name] = now - clock
        clock = now

    source = example_path("tree")
    stage(f"1/4 reading the example splat {source.name} and predicting its materials")
    tree = read_splat(source)
    annotated = annotate_cloud(tree, checkpoint=s.checkpoint, device=s.device, up="z")
    annotated.write(files["annotated"])
    mid = annotated.get("material_id")
    counts = {MATERIAL_NAMES.get(int(m), str(int(m))): int((mid == m).sum()) for m in np.unique(mid)}
    stage("   materials: " + ", ".join(f"{k} {v}" for k, v in counts.items()) + f" -> {files['annotated']}")
    lap("annotate")

    scene = Scene.from_dict(DEMO_SCENE, source="demo scene")
    scene.to_json(files["scene"])
    keep = subsample_per_cell(annotated, scene, s.particles_per_cell, s.seed)
    cloud = annotated.subset(keep)
    stage(f"2/4 simulating {len(cloud)} of {len(annotated)} Gaussians (≤ {s.particles_per_cell} per "
          f"{scene.dx * 100:.3g} cm cell) in wind for {(s.frames - 1) / s.fps:.2f} s")
    writer = FrameWriter(files["frames"], cloud, force=True)
    rec = viz.open_recording("pixie-demo", rrd_path=files["rrd"])
    x_world = np.empty((s.frames, len(cloud), 3), np.float32)

    def on_frame(state: FrameState) -> None:
        writer.write(state)
        x_world[state.index] = state.x_world
        if state.index == 0:
            _log_world(rec)
            viz.log_material_views(rec, cloud, time_s=0.0, means=state.x_world,
                                   radii=viz.splat_radii(cloud, scale=scene.object.size_m / _height(cloud)))
        else:
            viz.log_positions(rec, viz.MATERIAL_VIEW_ENTITIES, state.x_world, time_s=state.time_s)

    try:
        traj = simulate(cloud, scene, s.frames, s.fps, device=s.device, on_frame=on_frame)
        writer.finish(traj.t, traj.x)
        lap("simulate")
        stage(f"3/4 writing the rerun recording {files['rrd']}")
        viz.send_layout(rec, fps=s.fps, shared=["world"])
        viz.close_recording(rec)
    except BaseException:
        writer.abort()
        viz.discard_recording(rec)
        raise
    lap("record")

    stage(f"4/4 rendering {files['gif'].name} and {files['strip'].name}")
    colours = [cloud.rgb(), viz.material_colors(cloud.get("material_id"))]
    clip = render_clip(x_world, colours, ["colour", "material"], traj.t, s.image_size_px)
    save_gif(clip, files["gif"], fps=s.fps)
    save_png(strip(clip, traj.t, s.strip_frames), files["strip"])
    lap("render")

    z = cloud.means[:, 2]
    top = z >= np.quantile(z, 0.9)
    anchored = (cloud.get("material_id") == STATIONARY) | (z - z.min() <= 0.03 / scene.object.size_m * _height(cloud))
    return DemoResult(
        out_dir=out, files=files, gaussians=len(annotated), simulated=len(cloud), seconds=seconds,
        top_displacement=(traj.x[:, top] - traj.x[0, top]).mean(axis=1),
        anchored_max_displacement=float(np.abs(traj.x[:, anchored] - traj.x[0, anchored]).max())
        if anchored.any() else 0.0,
        material_counts=counts,
    )


def _height(cloud: SplatCloud) -> float:
    """Extent (input units) of the cloud's longest side (the tree's height)."""
    lo, hi = cloud.bounds()
    return float((hi - lo).max())


def _log_world(rec) -> None:
    """z-up view coordinates for the world (m) views of the recording."""
    if not rec.is_enabled():
        return
    import rerun as rr

    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
