"""`pixie demo`: the shipped potted tree, annotated by the shipped checkpoint, swaying in wind.

One end-to-end run of the product on a small CPU budget (< 2 minutes on a 2-core CPU):

1. read the example splat pixie_gs/data/examples/tree.ply (20k Gaussians, z up) and predict its
   materials with `annotate_cloud` → DIR/tree_annotated.ply (every Gaussian);
2. `run_scenario` (also used by examples/): keep at most `particles_per_cell` Gaussians per
   simulation grid cell (spatially even, so a thin trunk stays connected on the grid while dense
   foliage is thinned), simulate `DEMO_SCENE` (a 1 m tree under gravity, a gust along +x for
   0.8 s, base anchored) → DIR/frames/frame_*.ply + tracks.npz, streamed to DIR/demo.rrd (RGB |
   material | log E views side by side, time slider);
3. real Gaussian-splat renders (pixie_gs.gsrender) of the written frames, to open without rerun:
   DIR/demo.gif and DIR/demo_strip.png.

Gravity is on: the checkpoint gives the trunk wood values (the class table's tree trunk is wood,
1e9–1e10 Pa, 500–900 kg/m³; the paper's 2e6 Pa trunk buckles under its own crown), so the tree
stands under its own weight and its crown (~4e4 Pa) sways in the gust. On a CPU budget the
stiffest trunk particles are over the 400-substep budget and are held with the anchored pot (a
printed line says so); the rest of the trunk and the crown bend. Why 1 m: at 0.5 m the same tree
is stiff enough against a gust that it hardly moves (deflection under a body load grows with size).
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
RENDER_ENTITY = "render"  # recordings: the real splat renders of every frame (colour | material | log E)

# The demo's world (keys as in docs/scene.md). Gravity on; wind blows along +x for 0.8 s with a
# gust, then stops, so the tree bends downwind and swings back. The pot's base (lowest 6 cm) is
# anchored; the pot itself is held by its predicted `stationary` material.
ANCHORED_BASE_M = 0.06  # height of the anchored base (m), as in DEMO_SCENE["fixed"]
DEMO_SCENE: dict[str, Any] = {
    "up": "z",
    "object": {"size_m": 1.0, "position": [0.0, 0.0, 0.0]},
    "domain": {"size_m": 2.4, "grid": 32},
    "gravity": [0.0, 0.0, -9.81],
    "ground": {"enabled": True, "height_m": 0.0, "friction": 0.8},
    "damping": 0.5,
    "wind": [{"acceleration": [3.0, 0.0, 0.0], "start_s": 0.0, "end_s": 0.8,
              "gust_amplitude": 0.3, "gust_frequency_hz": 1.25}],
    "fixed": [{"region": {"min": [-2.0, -2.0, -0.2], "max": [2.0, 2.0, ANCHORED_BASE_M]}}],
    # caps the substeps a frame may take: parts stiffer than this allows are softened (and
    # reported), which bounds the run time whatever stiffness the model predicts
    "solver": {"max_substeps_per_frame": 400},
}


@dataclass
class DemoSettings:
    """Sizes that keep the demo under 2 minutes on a 2-core CPU (frames at `fps` frames/s)."""

    frames: int = 45
    fps: float = 15.0
    particles_per_cell: int = 6
    seed: int = 0
    device: str = "auto"
    checkpoint: str | Path | None = None  # None = the shipped checkpoint
    image_size_px: int = 240
    strip_frames: int = 6


@dataclass
class ScenarioResult:
    """What `run_scenario` wrote and computed. Positions of the simulated Gaussians: `traj.x`
    (T,N,3) in the input splat's coordinates, `x_world` (T,N,3) in world metres (z up)."""

    cloud: SplatCloud
    traj: object  # sim.run.Trajectory
    x_world: np.ndarray
    files: dict[str, Path]
    seconds: dict[str, float] = field(default_factory=dict)


@dataclass
class DemoResult:
    """What the demo wrote, and the measured motion (input units of the tree splat)."""

    out_dir: Path
    files: dict[str, Path]
    gaussians: int
    simulated: int
    seconds: dict[str, float] = field(default_factory=dict)
    top_displacement: np.ndarray | None = None  # (T,3) mean displacement of the top 10 % of the tree
    top_displacement_m: np.ndarray | None = None  # (T,3) the same in world metres (z up)
    height_m: float = 0.0  # the simulated tree's height (m)
    anchored_max_displacement: float = 0.0  # largest motion of any anchored (fixed/stationary) Gaussian
    material_counts: dict[str, int] = field(default_factory=dict)


def example_path(name: str) -> Path:
    """Path of an example splat shipped in the package (pixie_gs/data/examples/NAME.ply)."""
    if name not in EXAMPLE_NAMES:
        raise InputError(f"unknown example '{name}' (choose from {', '.join(EXAMPLE_NAMES)})")
    path = Path(str(resources.files("pixie_gs") / "data" / "examples" / f"{name}.ply"))
    if not path.is_file():
        raise InputError("shipped example splat is missing; reinstall pixie-gs", path)
    return path


def splat_views(frames_dir: Path, up: str, size_px: int, azimuth_deg: float, elevation_deg: float,
                device: str = "auto") -> list[list[np.ndarray]]:
    """Real 3DGS renders [frame][colour, material, log E] of the written frame files (every
    Gaussian, covariances as simulated), from one still camera that frames the whole run."""
    from .devices import resolve_torch_device
    from .gsrender.sequence import render_frames_dir

    views, _, _ = render_frames_dir(frames_dir, ["colour", "material", "logE"], size_px, 15.0, up, azimuth_deg,
                                    elevation_deg, resolve_torch_device(device), (1.0, 1.0, 1.0))
    return views


def animation_frames(views: list[list[np.ndarray]], labels: list[str], times_s: np.ndarray) -> list[np.ndarray]:
    """GIF frames: each frame's views side by side, labelled with the view name and time (s)."""
    from .render import contact_sheet

    return [contact_sheet(v, [f"{lab}  t = {t:.2f} s" for lab in labels], len(v)) for v, t in zip(views, times_s)]


def strip(views: list[list[np.ndarray]], labels: list[str], times_s: np.ndarray, count: int) -> np.ndarray:
    """`count` evenly spaced frames in columns, one row per view (a PNG summary of the animation)."""
    from .render import contact_sheet

    pick = np.unique(np.linspace(0, len(views) - 1, min(count, len(views))).round().astype(int))
    images = [views[i][k] for k in range(len(labels)) for i in pick]
    names = [f"{labels[k]}  t = {times_s[i]:.2f} s" for k in range(len(labels)) for i in pick]
    return contact_sheet(images, names, len(pick))


def prepare_out_dir(out_dir: str | Path) -> Path:
    """The demo's output directory (created; its own earlier files are replaced on success)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a directory, but a file of that name exists", out)
    if not out.exists() and not out.parent.is_dir():
        raise InputError("parent directory does not exist", out.parent)
    out.mkdir(exist_ok=True)
    return out


def material_summary(cloud: SplatCloud) -> dict[str, int]:
    """Gaussians per predicted material name, e.g. {"jelly": 17512, "stationary": 2946}."""
    from .materials import MATERIAL_NAMES

    mid = cloud.get("material_id")
    return {MATERIAL_NAMES.get(int(m), str(int(m))): int((mid == m).sum()) for m in np.unique(mid)}


def run_scenario(cloud: SplatCloud, scene, out_dir: Path, frames: int, fps: float, *, device: str = "auto",
                 particles_per_cell: int | None = 6, seed: int = 0, fill: bool = False, app_id: str = "pixie",
                 image_size_px: int = 240, strip_frames: int = 6, azimuth_deg: float = -90.0,
                 elevation_deg: float = 12.0, gif: bool = True) -> ScenarioResult:
    """Simulate an annotated `cloud` in `scene` and write, under `out_dir`: frames/frame_*.ply and
    frames/tracks.npz, run.rrd (RGB | material | log E views with a time slider, and the real splat
    renders of every frame under them), strip.png (a row
    per view, evenly spaced frames) and, with `gif`, run.gif. Used by the demo and examples/.

    particles_per_cell: simulate at most this many Gaussians per grid cell (None = all).
    """
    from . import viz
    from .render import save_gif, save_png
    from .sim.frames import FrameWriter
    from .sim.run import FrameState, simulate
    from .sim.subsample import Carrier, subsample_per_cell

    files = {"frames": out_dir / "frames", "rrd": out_dir / "run.rrd", "strip": out_dir / "strip.png"}
    if gif:
        files["gif"] = out_dir / "run.gif"
    seconds: dict[str, float] = {}
    clock = time.perf_counter()
    full_cloud = cloud
    carrier = None
    if particles_per_cell is not None:
        cloud = full_cloud.subset(subsample_per_cell(full_cloud, scene, particles_per_cell, seed))
        carrier = Carrier(full_cloud.means, cloud.means, full_cloud.get("material_id"), cloud.get("material_id"))
        stage(f"simulating {len(cloud)} of {len(full_cloud)} Gaussians (≤ {particles_per_cell} per "
              f"{scene.dx * 100:.3g} cm cell; the others move with their nearest simulated one) "
              f"for {(frames - 1) / fps:.2f} s")
    writer = FrameWriter(files["frames"], full_cloud, force=True)
    rec = viz.open_recording(app_id, rrd_path=files["rrd"])
    x_world = np.empty((frames, len(cloud), 3), np.float32)
    x_out = np.empty((frames, len(full_cloud), 3), np.float32)
    radii = viz.splat_radii(cloud, scale=scene.object.size_m / _longest_side(cloud))

    def on_frame(state: FrameState) -> None:
        full_state = state if carrier is None else carrier.carry(state)
        writer.write(full_state)
        x_out[state.index] = full_state.x
        x_world[state.index] = state.x_world
        if state.index == 0:
            _log_world(rec)
            viz.log_material_views(rec, cloud, time_s=0.0, means=state.x_world, radii=radii)
        else:
            viz.log_positions(rec, viz.MATERIAL_VIEW_ENTITIES, state.x_world, time_s=state.time_s)

    labels = ["colour", "material", "log10 E"]
    try:
        traj = simulate(cloud, scene, frames, fps, device=device, on_frame=on_frame, fill=fill)
        writer.finish(traj.t, x_out)
        seconds["simulate"] = time.perf_counter() - clock
        clock = time.perf_counter()
        views = splat_views(files["frames"], scene.up, image_size_px, azimuth_deg, elevation_deg, device)
        sheets = animation_frames(views, labels, traj.t)
        for picture, t in zip(sheets, traj.t):  # the real splat renders, under the 3D views
            viz.log_image(rec, RENDER_ENTITY, picture, time_s=float(t))
        viz.send_layout(rec, fps=fps, shared=["world"], images=[RENDER_ENTITY])
        viz.close_recording(rec)
    except BaseException:
        writer.abort()
        viz.discard_recording(rec)
        raise
    if gif:
        save_gif(sheets, files["gif"], fps=fps)
    save_png(strip(views, labels, traj.t, strip_frames), files["strip"])
    seconds["render"] = time.perf_counter() - clock
    return ScenarioResult(cloud=cloud, traj=traj, x_world=x_world, files=files, seconds=seconds)


def run_demo(out_dir: str | Path = "pixie_demo", settings: DemoSettings | None = None) -> DemoResult:
    """Annotate, simulate and picture the shipped potted tree; returns what was written."""
    from .annotate import annotate_cloud
    from .devices import resolve_torch_device, resolve_warp_device
    from .materials import STATIONARY
    from .sim.scene import Scene
    from .splat import read_splat

    s = settings or DemoSettings()
    if s.frames < 2:
        raise InputError(f"--frames must be ≥ 2 for an animation, got {s.frames}")
    resolve_torch_device(s.device)  # a device this machine lacks stops before anything is written
    resolve_warp_device(s.device)
    out = prepare_out_dir(out_dir)
    files = {"annotated": out / "tree_annotated.ply", "scene": out / "scene.json"}
    clock = time.perf_counter()

    source = example_path("tree")
    stage(f"1/3 reading the example splat {source.name} and predicting its materials")
    tree = read_splat(source)
    annotated = annotate_cloud(tree, checkpoint=s.checkpoint, device=s.device, up="z")
    annotated.write(files["annotated"])
    counts = material_summary(annotated)
    stage("    materials: " + ", ".join(f"{k} {v}" for k, v in counts.items()) + f" -> {files['annotated']}")
    seconds = {"annotate": time.perf_counter() - clock}

    scene = Scene.from_dict(DEMO_SCENE, source="demo scene")
    scene.to_json(files["scene"])
    stage("2/3 simulating the tree under gravity in a gust of wind (pot anchored)")
    result = run_scenario(annotated, scene, out, s.frames, s.fps, device=s.device,
                          particles_per_cell=s.particles_per_cell, seed=s.seed, app_id="pixie-demo",
                          image_size_px=s.image_size_px, strip_frames=s.strip_frames)
    stage("3/3 wrote frames, rerun recording, GIF and picture strip")
    renames = {"rrd": "demo.rrd", "gif": "demo.gif", "strip": "demo_strip.png"}
    for key, path in result.files.items():
        files[key] = path.replace(out / renames[key]) if key in renames else path
    seconds.update(result.seconds)

    cloud, traj = result.cloud, result.traj
    z = cloud.means[:, 2]
    top = z >= np.quantile(z, 0.9)
    base = z - z.min() <= ANCHORED_BASE_M / scene.object.size_m * _longest_side(cloud)
    anchored = (cloud.get("material_id") == STATIONARY) | base
    return DemoResult(
        out_dir=out, files=files, gaussians=len(annotated), simulated=len(cloud), seconds=seconds,
        top_displacement=(traj.x[:, top] - traj.x[0, top]).mean(axis=1),
        top_displacement_m=(result.x_world[:, top] - result.x_world[0, top]).mean(axis=1),
        height_m=float(np.ptp(result.x_world[0, :, 2])),
        anchored_max_displacement=float(np.abs(traj.x[:, anchored] - traj.x[0, anchored]).max()),
        material_counts=counts,
    )


def _longest_side(cloud: SplatCloud) -> float:
    """Extent (input units) of the cloud's longest bounding-box side (what object.size_m sets)."""
    lo, hi = cloud.bounds()
    return float((hi - lo).max())


def _log_world(rec) -> None:
    """z-up view coordinates for the world (m) views of the recording."""
    if not rec.is_enabled():
        return
    import rerun as rr

    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
