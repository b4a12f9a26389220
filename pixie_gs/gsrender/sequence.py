"""Rendered sequences: a splat file orbited, a simulation's frames from a fixed camera, or a
camera path; each picture is the chosen modes side by side, labelled, as one sheet."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from ..errors import InputError
from ..progress import progress
from . import MODE_LABELS, Gaussians, available_modes, frame_files, render_modes
from .camera import Camera, orbit_cameras

STRIP_FRAMES = 6  # a .png of a sequence shows this many evenly spaced frames


def pick_modes(cloud, modes: list[str] | None) -> list[str]:
    """`modes` checked against the cloud, or every mode it supports when None."""
    if modes is None:
        return available_modes(cloud)
    have = available_modes(cloud)
    for mode in modes:
        if mode not in have:
            from . import mode_colours

            mode_colours(cloud, mode)  # raises the one-line reason
    return list(modes)


def render_sheets(items: Iterable[tuple[object, Camera, str]], modes: list[str], device: str = "cpu",
                  background: tuple[float, float, float] = (1.0, 1.0, 1.0), total: int | None = None,
                  desc: str = "rendering") -> list[list[np.ndarray]]:
    """Images [item][mode] (uint8) for (cloud, camera, label) items."""
    out = []
    for cloud, cam, _ in progress(items, desc=desc, total=total, unit="frame"):
        out.append(render_modes(cloud, cam, modes, device=device, background=background))
    return out


def sheet(images: list[np.ndarray], modes: list[str], label: str = "") -> np.ndarray:
    """The mode images side by side, each labelled with its mode (and `label`, e.g. the time)."""
    from ..render import contact_sheet

    names = [f"{MODE_LABELS[m]}  {label}".strip() for m in modes]
    return contact_sheet(images, names, len(images))


def strip_sheet(views: list[list[np.ndarray]], modes: list[str], labels: list[str],
                count: int = STRIP_FRAMES) -> np.ndarray:
    """`count` evenly spaced items in columns, one row per mode (a still summary)."""
    from ..render import contact_sheet

    pick = np.unique(np.linspace(0, len(views) - 1, min(count, len(views))).round().astype(int))
    images = [views[i][k] for k in range(len(modes)) for i in pick]
    names = [f"{MODE_LABELS[modes[k]]}  {labels[i]}".strip() for k in range(len(modes)) for i in pick]
    return contact_sheet(images, names, len(pick))


def frame_times(frames_dir: Path, count: int, fps: float) -> np.ndarray:
    """Frame times (s): tracks.npz's `t` when it matches the frames, else index / fps."""
    tracks = Path(frames_dir) / "tracks.npz"
    if tracks.is_file():
        try:
            with np.load(tracks) as data:
                t = np.asarray(data["t"], np.float64)
            if len(t) == count and np.all(np.isfinite(t)):
                return t
        except Exception:  # an unreadable tracks file only loses the time labels
            pass
    return np.arange(count) / fps


def read_frames(files: list[Path]) -> Iterator[object]:
    from ..splat import read_splat

    for path in files:
        yield read_splat(path)


def sample_points(clouds_means: Iterable[np.ndarray], limit: int = 200_000, seed: int = 0) -> np.ndarray:
    """Up to `limit` centres drawn from several arrays of centres (for framing a whole run)."""
    rng = np.random.default_rng(seed)
    parts = list(clouds_means)
    per = max(1, limit // max(len(parts), 1))
    return np.concatenate([m if len(m) <= per else m[rng.choice(len(m), per, replace=False)] for m in parts])


def fixed_camera(points: np.ndarray, size_px: tuple[int, int], up, azimuth_deg: float,
                 elevation_deg: float) -> Camera:
    """One camera framing `points` from the given azimuth / elevation around `up`."""
    return orbit_cameras(points, 1, size_px[0], size_px[1], up=up, elevation_deg=elevation_deg,
                         azimuth0_deg=azimuth_deg)[0]


def check_sizes(width: int, height: int) -> None:
    if not (8 <= width <= 8192 and 8 <= height <= 8192):
        raise InputError(f"image size must be 8–8192 px per side (got {width}×{height})")


def render_frames_dir(frames_dir: Path, modes: list[str] | None, size_px: int, fps: float, up,
                      azimuth_deg: float, elevation_deg: float, device: str,
                      background: tuple[float, float, float], camera: Camera | None = None,
                      ) -> tuple[list[list[np.ndarray]], list[str], list[str]]:
    """Images [frame][mode] of a simulation's frames from one still camera (the given one, or one
    framing every frame), the modes drawn and a time label per frame."""
    files = frame_files(frames_dir)
    first = next(read_frames(files[:1]))
    modes = pick_modes(first, modes)
    if camera is None:
        stride = max(1, len(files) // 12)  # frame the run from a dozen frames spread over it
        points = sample_points(c.means for c in read_frames(files[::stride] + files[-1:]))
        camera = fixed_camera(points, (size_px, size_px), up, azimuth_deg, elevation_deg)
    times = frame_times(frames_dir, len(files), fps)
    labels = [f"t = {t:.2f} s" for t in times]
    items = ((c, camera, lab) for c, lab in zip(read_frames(files), labels))
    return render_sheets(items, modes, device, background, total=len(files)), modes, labels


def render_splat_file(cloud, modes: list[str] | None, cameras: list[Camera], device: str,
                      background: tuple[float, float, float]) -> tuple[list[list[np.ndarray]], list[str], list[str]]:
    """Images [camera][mode] of one splat seen by each camera, the modes and a label per camera."""
    modes = pick_modes(cloud, modes)
    g = Gaussians.from_cloud(cloud, device)
    views = []
    for cam in progress(cameras, desc="rendering", unit="view"):
        views.append(render_modes(cloud, cam, modes, device=device, background=background, gaussians=g))
    labels = [cam.name if not cam.name.startswith("orbit_") else "" for cam in cameras]
    return views, modes, labels
