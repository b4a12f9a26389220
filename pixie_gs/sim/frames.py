"""Writing simulation output: DIR/frame_00000.ply … and DIR/tracks.npz.

Each frame is a valid 3DGS file with every property of the input kept (extras included, byte for
byte where the simulation did not change it): positions moved, and covariances advanced
Σ' = F Σ Fᵀ and written back as scale/rotation, all in the input splat's coordinates.
`tracks.npz` holds `t` (T,) s and `x` (T,N,3) — the format `pixie diagnose` reads as measured
data. Every file is written atomically; a run that fails removes the files it wrote.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import InputError
from ..splat import SplatCloud, write_splat
from .run import FrameState

FRAME_PATTERN = re.compile(r"frame_(\d{5,})\.ply")
TRACKS_NAME = "tracks.npz"
PREVIEW_NAME = "preview.png"
PREVIEW_MAX_POINTS = 60_000  # preview renders a fixed random subset of at most this many Gaussians


def frame_path(out_dir: str | Path, index: int) -> Path:
    return Path(out_dir) / f"frame_{index:05d}.ply"


def existing_outputs(out_dir: Path) -> list[Path]:
    """Frame files, tracks.npz and preview.png already in `out_dir` (sorted)."""
    if not out_dir.is_dir():
        return []
    return sorted(p for p in out_dir.iterdir()
                  if FRAME_PATTERN.fullmatch(p.name) or p.name in (TRACKS_NAME, PREVIEW_NAME))


def check_output_dir(out_dir: str | Path, force: bool = False) -> Path:
    """Refuse an output that is a file, or a directory holding earlier frames (unless `force`).
    Creates nothing (call before any work so bad arguments leave no trace)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a directory, but a file of that name exists", out)
    old = existing_outputs(out)
    if old and not force:
        raise InputError(f"already holds simulation output ({old[0].name}, {len(old)} files); "
                         "use --force to overwrite or choose another --out", out)
    if not out.exists() and not out.parent.exists():
        raise InputError("parent directory does not exist", out.parent)
    return out


def advance_covariances(cov0: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Σ' = F Σ Fᵀ for (N,3,3) arrays (float64), via sim-core's advect_covariances."""
    from .covariance import advect_covariances

    return np.asarray(advect_covariances(np.asarray(cov0, np.float64), np.asarray(F, np.float64)), np.float64)


def frame_cloud(base: SplatCloud, cov0: np.ndarray, state: FrameState, tol: float = 0.0) -> SplatCloud:
    """`base` moved to `state`: new means, and scale/rotation from F Σ Fᵀ for the Gaussians whose
    F differs from the identity by more than `tol` (the others keep their stored bytes)."""
    # a shallow view of `base`: only the arrays the simulation changes are new
    out = SplatCloud(means=np.ascontiguousarray(state.x, np.float32), log_scales=base.log_scales,
                     rotations=base.rotations, opacity_logits=base.opacity_logits, sh_dc=base.sh_dc,
                     sh_rest=base.sh_rest, extras=base.extras, property_order=base.property_order,
                     source=base.source)
    if state.F is None:
        return out
    F = np.asarray(state.F, np.float64)
    changed = np.abs(F - np.eye(3)).reshape(len(F), 9).max(axis=1) > tol
    if changed.any():
        idx = np.flatnonzero(changed)
        out.log_scales = base.log_scales.copy()
        out.rotations = base.rotations.copy()
        part = SplatCloud(means=out.means[idx], log_scales=out.log_scales[idx], rotations=out.rotations[idx],
                          opacity_logits=out.opacity_logits[idx], sh_dc=out.sh_dc[idx],
                          sh_rest=out.sh_rest[idx])
        part.set_covariances(advance_covariances(cov0[idx], F[idx]))
        out.log_scales[idx] = part.log_scales
        out.rotations[idx] = part.rotations
    return out


class FrameWriter:
    """Streams frames of one run into `out_dir` (created on the first write).

    Use: `w = FrameWriter(dir, cloud, force)`; `w.write(state)` per frame (the `on_frame` of
    `simulate`); `w.write_preview(t, x, up)` a PNG strip of the run; `w.finish(t, x)` writes
    tracks.npz and removes stale outputs of an earlier run (call it last); `w.abort()` on
    failure removes everything this run wrote.
    """

    def __init__(self, out_dir: str | Path, cloud: SplatCloud, force: bool = False) -> None:
        self.out_dir = check_output_dir(out_dir, force)
        self.base = cloud.copy()
        self.cov0 = cloud.covariances()
        self.written: list[Path] = []
        self._created_dir = False

    def _ensure_dir(self) -> None:
        if not self.out_dir.exists():
            self.out_dir.mkdir()
            self._created_dir = True

    def write(self, state: FrameState) -> Path:
        self._ensure_dir()
        path = frame_path(self.out_dir, state.index)
        write_splat(frame_cloud(self.base, self.cov0, state), path)
        self.written.append(path)
        return path

    def finish(self, t_s: np.ndarray, x: np.ndarray) -> Path:
        """Write tracks.npz (t (T,) s, x (T,N,3) input coordinates) and drop stale frames."""
        self._ensure_dir()
        path = write_tracks(self.out_dir / TRACKS_NAME, t_s, x)
        self.written.append(path)
        keep = set(self.written)
        for old in existing_outputs(self.out_dir):
            if old not in keep:
                old.unlink()
        return path

    def write_preview(self, t_s: np.ndarray, x: np.ndarray, up: str, panels: int = 6) -> Path:
        """preview.png: a strip of `panels` evenly spaced frames (input coordinates viewed with
        `up` upwards, fixed bounds over the whole run so motion shows), coloured by RGB."""
        from ..render import contact_sheet, render_points, save_png

        self._ensure_dir()
        x = np.asarray(x)
        n = x.shape[1]
        pick = np.arange(n) if n <= PREVIEW_MAX_POINTS else \
            np.sort(np.random.default_rng(0).choice(n, PREVIEW_MAX_POINTS, replace=False))
        frames = np.unique(np.linspace(0, len(t_s) - 1, min(panels, len(t_s))).round().astype(int))
        pts = x[:, pick].reshape(-1, 3)
        bounds = (pts.min(axis=0), pts.max(axis=0))
        rgb = self.base.rgb()[pick]
        images = [render_points(x[i, pick], rgb, size=(220, 220), up=up, bounds=bounds) for i in frames]
        path = self.out_dir / PREVIEW_NAME
        save_png(contact_sheet(images, [f"t = {t_s[i]:.3f} s" for i in frames], columns=len(frames)), path)
        self.written.append(path)
        return path

    def abort(self) -> None:
        """Remove what this run wrote (and the directory, if this run created it and it is empty)."""
        for path in self.written:
            path.unlink(missing_ok=True)
        self.written.clear()
        if self._created_dir and self.out_dir.is_dir() and not any(self.out_dir.iterdir()):
            self.out_dir.rmdir()


def write_tracks(path: str | Path, t_s: np.ndarray, x: np.ndarray) -> Path:
    """tracks.npz with `t` (T,) float64 s and `x` (T,N,3) float32, written atomically."""
    t_s = np.asarray(t_s, np.float64).reshape(-1)
    x = np.asarray(x, np.float32)
    if x.ndim != 3 or x.shape[0] != len(t_s) or x.shape[2] != 3:
        raise ValueError(f"tracks: x has shape {x.shape}, expected ({len(t_s)}, N, 3)")
    with atomic_path(path, suffix=".npz.tmp") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, t=t_s, x=x)
    return Path(path)
