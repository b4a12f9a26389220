"""Rerun recordings of splats: RGB, material class, log-stiffness and confidence views over a time slider.

Used by `annotate`, `simulate`, `diagnose` and `demo`. Typical use::

    rec = open_recording("pixie-simulate", rrd_path="run.rrd", spawn=False)
    log_material_views(rec, cloud, time_s=0.0)          # splat/rgb, /material, /log_E, /confidence
    for t, x in ...: log_positions(rec, MATERIAL_VIEW_ENTITIES, x, time_s=t)
    send_layout(rec)                                    # four 3D views side by side + time panel
    close_recording(rec)                                # the .rrd appears only now (atomic)

`open_recording` always returns a recording; with neither `rrd_path` nor `spawn` it is a
`NullRecording` whose methods do nothing, so callers can log unconditionally at no cost. The `.rrd` is written to a hidden
temporary file next to the target and renamed onto it by `close_recording`, so a failed run never
leaves a partial recording (an unclosed temporary file is removed when the process exits).
Times are seconds on the timeline `TIMELINE` ("time"); `time_s=None` logs static data, shown at
every time. Positions are logged in whatever coordinates the caller passes (metres for world data).
"""
from __future__ import annotations

import atexit
import contextlib
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Sequence

import numpy as np

from .errors import InputError
from .interrupts import raise_if_interrupted
from .materials import LOG10_E_RANGE, MATERIAL_COLORS, MATERIAL_NAMES

if TYPE_CHECKING:  # rerun is a heavy import; only load it when a recording is made
    import rerun as rr

    from .splat import SplatCloud

TIMELINE = "time"
DEFAULT_ROOT = "splat"
VIEW_NAMES = {"rgb": "colour (RGB)", "material": "material class", "log_E": "log10 E (Pa)",
              "confidence": "material confidence"}
MATERIAL_VIEW_ENTITIES = tuple(f"{DEFAULT_ROOT}/{k}" for k in VIEW_NAMES)

# temporary .rrd path -> final path, for recordings opened with rrd_path and not yet closed
_PENDING: dict[int, tuple[Path, Path]] = {}


def _remove_unclosed_temporaries() -> None:
    for tmp, _final in list(_PENDING.values()):
        with contextlib.suppress(OSError):
            tmp.unlink()


atexit.register(_remove_unclosed_temporaries)


# ---------------------------------------------------------------------------------- recordings
class NullRecording:
    """Stands in for a disabled `rr.RecordingStream`: every call is a no-op (and, unlike a
    disabled rerun stream, it prints no warnings at exit)."""

    def __init__(self, app_id: str = "pixie") -> None:
        self.app_id = app_id

    def is_enabled(self) -> bool:
        return False

    def _ignore(self, *args, **kwargs) -> None:
        return None

    log = set_time = flush = disconnect = send_blueprint = send_columns = reset_time = _ignore


def open_recording(app_id: str, rrd_path: str | Path | None = None, spawn: bool = False) -> "rr.RecordingStream":
    """A recording stream that saves to `rrd_path` (atomically, see `close_recording`) and/or
    streams to a freshly spawned viewer (`spawn=True`); a do-nothing `NullRecording` when neither."""
    import rerun as rr

    if rrd_path is None and not spawn:
        return NullRecording(app_id)  # type: ignore[return-value]
    rec = rr.RecordingStream(app_id)
    sinks = []
    if rrd_path is not None:
        final = Path(rrd_path)
        directory = final.parent if str(final.parent) else Path(".")
        if not directory.is_dir():
            raise InputError("directory for the rerun recording does not exist", directory)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=directory)
        os.close(fd)
        _PENDING[id(rec)] = (Path(tmp_name), final)
        sinks.append(rr.FileSink(tmp_name))
    if spawn:
        if sys.platform.startswith("linux") and not any(
                os.environ.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")):
            discard_recording(rec)
            raise InputError("--spawn needs a display for the rerun viewer (none here); record with "
                             "--rrd FILE and open it with `rerun FILE` instead")
        try:
            rr.spawn(connect=False, hide_welcome_screen=True, recording=rec)
        except Exception as exc:  # no viewer binary, no display, ...
            discard_recording(rec)
            raise InputError(f"--spawn: could not start the rerun viewer ({exc})") from None
        sinks.append(rr.GrpcSink())
    rec.set_sinks(*sinks)
    return rec


def close_recording(rec: "rr.RecordingStream") -> Path | None:
    """Flush `rec`; if it saves to a file, move the finished file onto its target and return it."""
    if not rec.is_enabled():
        return None
    try:
        rec.flush(timeout_sec=10.0)
    except RuntimeError as exc:  # a live viewer that went away must not fail a finished run
        from .progress import stage

        stage(f"rerun: live stream not delivered ({str(exc).splitlines()[0]})")
    rec.disconnect()
    pending = _PENDING.pop(id(rec), None)
    if pending is None:
        return None
    tmp, final = pending
    raise_if_interrupted()  # a Ctrl-C/SIGTERM swallowed in a finalizer must not publish the recording
    os.replace(tmp, final)
    return final


def discard_recording(rec: "rr.RecordingStream") -> None:
    """Stop `rec` and delete its unfinished file (for error paths: no partial output)."""
    pending = _PENDING.pop(id(rec), None)
    if rec.is_enabled():
        rec.disconnect()
    if pending is not None:
        with contextlib.suppress(OSError):
            pending[0].unlink()


@contextlib.contextmanager
def recording(app_id: str, rrd_path: str | Path | None = None, spawn: bool = False):
    """`open_recording` as a context manager: closed (file published) on success, discarded on error."""
    rec = open_recording(app_id, rrd_path, spawn)
    try:
        yield rec
    except BaseException:
        discard_recording(rec)
        raise
    close_recording(rec)


def _set_time(rec: "rr.RecordingStream", time_s: float | None) -> bool:
    """Point `rec` at `time_s` on the time line; returns whether the next log is static."""
    if time_s is None:
        return True
    rec.set_time(TIMELINE, duration=float(time_s))
    return False


# ---------------------------------------------------------------------------------- colours
def material_colors(material_id: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] (N,3) for material ids (unknown ids shown as background black)."""
    ids = np.asarray(material_id, dtype=np.int64)
    ids = np.where((ids >= 0) & (ids < len(MATERIAL_COLORS)), ids, len(MATERIAL_COLORS) - 1)
    return MATERIAL_COLORS[ids]


def log_e_colors(E_pa: np.ndarray, cmap: str = "viridis") -> np.ndarray:
    """RGB in [0, 1] (N,3) mapping log10 E over the fixed dataset range, so files compare."""
    from matplotlib import colormaps

    lo, hi = LOG10_E_RANGE
    u = (np.log10(np.maximum(np.asarray(E_pa, dtype=np.float64), 1e-30)) - lo) / (hi - lo)
    return colormaps[cmap](np.clip(u, 0.0, 1.0))[:, :3].astype(np.float32)


def confidence_colors(confidence: np.ndarray, cmap: str = "magma") -> np.ndarray:
    """RGB in [0, 1] (N,3) for per-Gaussian confidence in [0, 1] (dark: a guess, bright: trusted);
    the same map `pixie render --mode confidence` uses."""
    from matplotlib import colormaps

    c = np.nan_to_num(np.asarray(confidence, dtype=np.float64), nan=0.0)
    return colormaps[cmap](np.clip(c, 0.0, 1.0))[:, :3].astype(np.float32)


def splat_radii(cloud: "SplatCloud", scale: float = 1.0) -> np.ndarray:
    """Point radii (N,) from each Gaussian's geometric-mean std-dev, in the cloud's length unit."""
    return (scale * np.exp(cloud.log_scales.astype(np.float64).mean(axis=1))).astype(np.float32)


# ---------------------------------------------------------------------------------- logging
def log_splat(
    rec: "rr.RecordingStream",
    entity: str,
    cloud_or_means: "SplatCloud | np.ndarray",
    rgb: np.ndarray | None = None,
    radii: np.ndarray | float | None = None,
    time_s: float | None = None,
) -> None:
    """Log Gaussians as 3D points at `entity`.

    With a SplatCloud, colours default to its base RGB and radii to its std-devs. With a bare
    (N,3) array only what is given is logged: later calls with positions alone move the points
    and keep the colours/radii logged earlier (rerun's latest-at), which keeps long runs small.
    Beware: static data (time_s=None) shadows every temporal value of the same component in
    rerun, so to style points that move later, use `log_style` (colours/radii only) or log the
    first positions at the first time instead of statically.
    """
    import rerun as rr

    if not rec.is_enabled():
        return
    if isinstance(cloud_or_means, np.ndarray):
        means = cloud_or_means
    else:
        cloud = cloud_or_means
        means = cloud.means
        rgb = cloud.rgb() if rgb is None else rgb
        radii = splat_radii(cloud) if radii is None else radii
    means = np.asarray(means, dtype=np.float32).reshape(-1, 3)
    if radii is not None and np.ndim(radii) == 0:
        radii = np.full(len(means), float(radii), np.float32)
    static = _set_time(rec, time_s)
    rec.log(entity, rr.Points3D.from_fields(positions=means, colors=rgb, radii=radii), static=static)


def log_style(rec: "rr.RecordingStream", entity: str, rgb: np.ndarray | None = None,
              radii: np.ndarray | float | None = None) -> None:
    """Static colours (N,3)/(3,) and radii of `entity` only, so positions logged over time move
    the points while keeping this look (a single colour/radius applies to every point)."""
    import rerun as rr

    if not rec.is_enabled():
        return
    rgb = None if rgb is None else np.atleast_2d(np.asarray(rgb))
    radii = None if radii is None else np.atleast_1d(np.asarray(radii, np.float32))
    rec.log(entity, rr.Points3D.from_fields(colors=rgb, radii=radii), static=True)


def log_positions(rec: "rr.RecordingStream", entities: Iterable[str], means: np.ndarray,
                  time_s: float | None = None) -> None:
    """Move the points of each of `entities` to `means` (N,3) at `time_s` (colours are kept)."""
    for entity in entities:
        log_splat(rec, entity, np.asarray(means), time_s=time_s)


def log_material_legend(rec: "rr.RecordingStream", entity: str) -> None:
    """A static annotation context naming each material id with its display colour."""
    import rerun as rr

    if not rec.is_enabled():
        return
    rec.log(entity, rr.AnnotationContext(
        [(i, MATERIAL_NAMES[i], (MATERIAL_COLORS[i] * 255).astype(np.uint8)) for i in MATERIAL_NAMES]
    ), static=True)


def log_material_views(rec: "rr.RecordingStream", cloud: "SplatCloud", time_s: float | None = None,
                       root: str = DEFAULT_ROOT, means: np.ndarray | None = None,
                       radii: np.ndarray | float | None = None) -> tuple[str, ...]:
    """Log `cloud` four times under `root`: `rgb` (base colour), `material` (class colours, with
    class ids for hover labels), `log_E` (viridis over log10 E) and `confidence` (magma over the
    per-Gaussian `confidence` annotate writes, 0–1). Views whose attribute the cloud lacks are grey.
    `means` overrides positions (e.g. world coordinates). Returns the entity paths, the same as
    `MATERIAL_VIEW_ENTITIES` for the default root (for `log_positions` and `send_layout`)."""
    import rerun as rr

    entities = tuple(f"{root}/{k}" for k in VIEW_NAMES)
    if not rec.is_enabled():
        return entities
    pos = np.asarray(cloud.means if means is None else means, dtype=np.float32).reshape(-1, 3)
    r = splat_radii(cloud) if radii is None else radii
    if r is not None and np.ndim(r) == 0:
        r = np.full(len(pos), float(r), np.float32)
    grey = np.full((len(pos), 3), 0.5, np.float32)
    log_material_legend(rec, f"{root}/material")
    static = _set_time(rec, time_s)
    rec.log(entities[0], rr.Points3D(pos, colors=cloud.rgb(), radii=r), static=static)
    if cloud.has("material_id"):
        ids = cloud.get("material_id").astype(np.int64)
        rec.log(entities[1], rr.Points3D(pos, colors=material_colors(ids), radii=r,
                                         class_ids=ids.astype(np.uint16)), static=static)
    else:
        rec.log(entities[1], rr.Points3D(pos, colors=grey, radii=r), static=static)
    E_colors = log_e_colors(cloud.get("E")) if cloud.has("E") else grey
    rec.log(entities[2], rr.Points3D(pos, colors=E_colors, radii=r), static=static)
    conf_colors = confidence_colors(cloud.get("confidence")) if cloud.has("confidence") else grey
    rec.log(entities[3], rr.Points3D(pos, colors=conf_colors, radii=r), static=static)
    return entities


def log_image(rec: "rr.RecordingStream", entity: str, image: np.ndarray, time_s: float | None = None) -> None:
    """An RGB picture (H,W,3 uint8, e.g. a real splat render of one frame) at `time_s`, JPEG-compressed."""
    import rerun as rr

    if not rec.is_enabled():
        return
    static = _set_time(rec, time_s)
    rec.log(entity, rr.Image(np.ascontiguousarray(image[:, :, :3], np.uint8)).compress(jpeg_quality=85),
            static=static)


def log_scalar(rec: "rr.RecordingStream", entity: str, value: float, time_s: float | None = None) -> None:
    """A scalar time series point (e.g. kinetic energy, gap to measurement) at `time_s`."""
    import rerun as rr

    if not rec.is_enabled():
        return
    static = _set_time(rec, time_s)
    rec.log(entity, rr.Scalars(float(value)), static=static)


def send_layout(rec: "rr.RecordingStream", entities: Sequence[str] = MATERIAL_VIEW_ENTITIES,
                names: Sequence[str] | None = None, plots: Sequence[str] = (),
                fps: float | None = None, shared: Sequence[str] = (), images: Sequence[str] = ()) -> None:
    """Send a blueprint: one 3D view per entity side by side (default the four material views),
    each also showing the `shared` entities (e.g. a ground plane), optional 2D views of `images`
    (e.g. real splat renders, `log_image`) and time-series plots below them, and an expanded time
    panel on the `time` line."""
    import rerun.blueprint as rrb

    if not rec.is_enabled():
        return
    if names is None:
        names = [VIEW_NAMES.get(e.rsplit("/", 1)[-1], e) for e in entities]
    common = [f"/{e.strip('/')}/**" for e in shared]
    views = [rrb.Spatial3DView(origin="/", contents=[f"/{e.strip('/')}/**", *common], name=n)
             for e, n in zip(entities, names)]
    top = rrb.Horizontal(*views)
    if images:
        top = rrb.Vertical(top, rrb.Horizontal(*[rrb.Spatial2DView(origin=f"/{e.strip('/')}", name=e.strip("/"))
                                                for e in images]), row_shares=[3, 2])
    if plots:
        layout = rrb.Vertical(top, rrb.Horizontal(*[rrb.TimeSeriesView(origin=f"/{p.strip('/')}", name=p)
                                                   for p in plots]), row_shares=[3, 1])
    else:
        layout = top
    panel = rrb.TimePanel(state="expanded", timeline=TIMELINE, fps=fps) if fps else \
        rrb.TimePanel(state="expanded", timeline=TIMELINE)
    rec.send_blueprint(rrb.Blueprint(layout, panel, rrb.SelectionPanel(state="collapsed"),
                                     collapse_panels=False))


# ---------------------------------------------------------------------------------- reading back
def read_recording_entities(rrd_path: str | Path) -> dict[str, int]:
    """Entity path -> number of logged rows in a saved `.rrd` (for tests and checks)."""
    from rerun.chunk import RrdReader

    counts: dict[str, int] = {}
    for chunk in RrdReader(str(rrd_path)).stream().to_chunks():
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts


def read_recording_positions(rrd_path: str | Path, entity: str) -> list[tuple[float | None, np.ndarray]]:
    """(time s or None for static, positions (N,3)) for every Points3D row of `entity`, in time order."""
    from rerun.chunk import RrdReader

    entity = "/" + entity.strip("/")
    rows: list[tuple[float | None, np.ndarray]] = []
    for chunk in RrdReader(str(rrd_path)).stream().to_chunks():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if "Points3D:positions" not in names:
            continue
        col = batch.column("Points3D:positions")
        # durations as integer nanoseconds: pyarrow's timedelta conversion rejects sub-µs values
        times = (batch.column(TIMELINE).cast("int64").to_pylist() if TIMELINE in names
                 else [None] * batch.num_rows)
        for i in range(batch.num_rows):
            cell = col[i]
            if not cell.is_valid:
                continue
            t = times[i]
            t_s = None if t is None else float(t) * 1e-9
            xyz = np.asarray(cell.values.flatten().to_numpy(zero_copy_only=False), np.float32).reshape(-1, 3)
            rows.append((t_s, xyz))
    rows.sort(key=lambda r: -1.0 if r[0] is None else r[0])
    return rows
