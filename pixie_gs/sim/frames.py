"""Writing simulation output: DIR/frame_00000.ply … and DIR/tracks.npz.

Each frame is a valid 3DGS file with every property of the input kept (extras included, byte for
byte where the simulation did not change it): positions moved, and covariances advanced
Σ' = F Σ Fᵀ and written back as scale/rotation, all in the input splat's coordinates.
`tracks.npz` holds `t` (T,) s and `x` (T,N,3) — the format `pixie diagnose` reads as measured
data. A run is written into a staging folder beside DIR and swapped in whole when complete, so
DIR holds either the previous run or the new one, never a mix (see FrameWriter).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import ComputationError, InputError, require_finite_result
from ..interrupts import raise_if_interrupted
from ..splat import SplatCloud, write_splat
from .run import FrameState

FRAME_PATTERN = re.compile(r"frame_(\d{5,})\.ply")
TRACKS_NAME = "tracks.npz"
_TRACK_BUFFER = ".tracks.npy"  # memory-mapped (T,N,3) positions while the run lasts (staging only)
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


def check_output_dir(out_dir: str | Path, force: bool = False, inputs: tuple[str | Path, ...] = ()) -> Path:
    """Refuse an output that is a file, a directory holding earlier frames (unless `force`), a
    directory holding any of `inputs` or sub-folders (it is replaced as a whole), or one that holds
    the current directory. Creates nothing (call before any work so bad arguments leave no trace)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a directory, but a file of that name exists", out)
    if not out.exists() and not out.parent.exists():
        raise InputError("parent directory does not exist", out.parent)
    if not out.exists():
        return out
    resolved = out.resolve()
    for inp in inputs:
        if inp is not None and resolved in Path(inp).resolve().parents:
            raise InputError(f"holds the input {Path(inp).name}; the output folder is replaced as a whole, "
                             "so choose an --out that does not contain the inputs", out)
    if resolved == Path.cwd().resolve() or resolved in Path.cwd().resolve().parents:
        raise InputError("is the current directory (or holds it); choose a sub-folder for --out", out)
    old = existing_outputs(out)
    if old and not force:
        raise InputError(f"already holds simulation output ({old[0].name}, {len(old)} files); "
                         "use --force to overwrite or choose another --out", out)
    folders = [p.name for p in out.iterdir() if p.is_dir() and not p.is_symlink()]
    if folders:
        raise InputError(f"holds the folder '{folders[0]}'; the output folder is replaced as a whole, "
                         "so choose an --out without sub-folders", out)
    return out


def _is_output_name(name: str) -> bool:
    return bool(FRAME_PATTERN.fullmatch(name)) or name in (TRACKS_NAME, PREVIEW_NAME)


def estimate_output_bytes(cloud: SplatCloud, frames: int) -> int:
    """Disk a run of `frames` frames writes (bytes): frame files, tracks.npz and its staging copy."""
    per_vertex = _vertex_bytes(cloud)
    return int(frames) * (len(cloud) * per_vertex + 4096) + 2 * int(frames) * len(cloud) * 12


def _vertex_bytes(cloud: SplatCloud) -> int:
    n_float = 14 + cloud.sh_rest.shape[1]
    return 4 * n_float + sum(v.dtype.itemsize for v in cloud.extras.values())


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
    """Streams frames of one run into a staging folder beside `out_dir`, swapped in whole at the end.

    Use: `w = FrameWriter(dir, cloud, force, frames=T)`; pass `w.positions` (a memory-mapped
    (T,N,3) float32 array in the staging folder, so memory stays flat) to `simulate`; `w.write(state)`
    per frame (the `on_frame` of `simulate`); `w.write_preview(t, x, up)` a PNG strip of the run;
    `w.finish(t, x)` writes tracks.npz and replaces `out_dir` by the staged run (old output kept
    until then, and kept whole if the run fails or is killed); `w.abort()` on failure removes the
    staging folder. Other files already in `out_dir` are kept (hard-linked into the new folder).
    """

    def __init__(self, out_dir: str | Path, cloud: SplatCloud, force: bool = False, frames: int | None = None,
                 inputs: tuple[str | Path, ...] = ()) -> None:
        from ..atomic import StagedDirectory

        self.out_dir = check_output_dir(out_dir, force, inputs)
        self.base = cloud.copy()
        self.cov0 = cloud.covariances()
        self.written: list[Path] = []
        self.positions = None
        self.staging = StagedDirectory(self.out_dir)
        try:  # from here on, any failure or signal removes the staging folder
            if frames is not None:
                self.positions = np.lib.format.open_memmap(self.staging.path / _TRACK_BUFFER, mode="w+",
                                                           dtype=np.float32, shape=(int(frames), len(cloud), 3))
        except BaseException:
            self.abort()
            raise

    @property
    def stage_dir(self) -> Path:
        return self.staging.path

    def write(self, state: FrameState) -> Path:
        raise_if_interrupted()  # once per frame: a signal swallowed in a finalizer stops the run here
        frame = frame_cloud(self.base, self.cov0, state)
        require_finite_result({"positions": frame.means, "scales": frame.log_scales, "rotations": frame.rotations},
                              f"frame {state.index}", self.out_dir)
        path = frame_path(self.stage_dir, state.index)
        try:
            write_splat(frame, path)
        except InputError as exc:  # out-of-range values the simulation produced: a failed computation
            raise ComputationError(f"frame {state.index} is not a valid splat ({exc})", self.out_dir) from None
        self.written.append(path)
        return path

    def finish(self, t_s: np.ndarray, x: np.ndarray) -> Path:
        """Write tracks.npz (t (T,) s, x (T,N,3) input coordinates), then swap the staged run in."""
        require_finite_result({"track positions": x}, "tracks", self.out_dir)
        write_tracks(self.stage_dir / TRACKS_NAME, t_s, x)
        if self.positions is not None:
            del x
            self.positions = None
            (self.stage_dir / _TRACK_BUFFER).unlink(missing_ok=True)
        self.staging.commit(keep=lambda name: not _is_output_name(name))
        self.written = [self.out_dir / p.name for p in self.written] + [self.out_dir / TRACKS_NAME]
        return self.out_dir / TRACKS_NAME

    def write_preview(self, t_s: np.ndarray, x: np.ndarray, up: str, panels: int = 6) -> Path:
        """preview.png: a strip of `panels` evenly spaced frames (input coordinates viewed with
        `up` upwards, fixed bounds over the whole run so motion shows), coloured by RGB."""
        from ..render import contact_sheet, render_points, save_png

        x = np.asarray(x)
        n = x.shape[1]
        pick = np.arange(n) if n <= PREVIEW_MAX_POINTS else \
            np.sort(np.random.default_rng(0).choice(n, PREVIEW_MAX_POINTS, replace=False))
        frames = np.unique(np.linspace(0, len(t_s) - 1, min(panels, len(t_s))).round().astype(int))
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for start in range(0, len(x), 256):  # bounds over the whole run, a chunk of frames at a time
            chunk = x[start:start + 256, pick].reshape(-1, 3)
            lo, hi = np.minimum(lo, chunk.min(axis=0)), np.maximum(hi, chunk.max(axis=0))
        bounds = (lo.astype(np.float32), hi.astype(np.float32))
        rgb = self.base.rgb()[pick]
        images = [render_points(x[i, pick], rgb, size=(220, 220), up=up, bounds=bounds) for i in frames]
        path = self.stage_dir / PREVIEW_NAME
        save_png(contact_sheet(images, [f"t = {t_s[i]:.3f} s" for i in frames], columns=len(frames)), path)
        self.written.append(path)
        return path

    def abort(self) -> None:
        """Remove the staging folder (the previous output, if any, is untouched)."""
        self.positions = None
        self.staging.abort()
        self.written.clear()


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
