"""Write the improved model, re-simulate it, and show the gap before/after (JSON, PNG, rerun).

Output directory layout:
  scene.json        the improved scene (scene effects as scene keys; yield / anchoring as
                    part_overrides)
  model.ply         the splat with updated material attributes (E, density scaled for the part)
                    — written when a material effect was added or parts had to be derived
  report.json       rankings with evidence per round, gaps per region, runs and timings
  gap.png           residual over time before/after, per-region bars, candidate ranking
  diagnose.rrd      rerun recording: measured vs simulated tracked points before/after
"""
from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..splat import SplatCloud
from .locate import per_frame_rms, residuals, rms_gap, spatial_clusters
from .measured import MeasuredTracks
from .ambiguity import separation_hint
from .pipeline import Diagnosis


def bake_material_overrides(scene, cloud: SplatCloud) -> tuple[object, SplatCloud]:
    """Move part E/density scale factors from `scene.part_overrides` into the cloud's `E` and
    `density` attributes (copies); overrides left at their defaults are dropped."""
    scene = copy.deepcopy(scene)
    cloud = cloud.copy()
    part = cloud.get("part_id") if cloud.has("part_id") else None
    for pid, o in list(scene.part_overrides.items()):
        if part is not None and (o.E_scale != 1.0 or o.density_scale != 1.0):
            sel = part == pid
            if cloud.has("E"):
                E = cloud.get("E").astype(np.float64)
                E[sel] *= o.E_scale
                cloud.set("E", E, np.float32)
            if cloud.has("density"):
                rho = cloud.get("density").astype(np.float64)
                rho[sel] *= o.density_scale
                cloud.set("density", rho, np.float32)
            o.E_scale = 1.0
            o.density_scale = 1.0
        if o.E_scale == 1.0 and o.density_scale == 1.0 and o.yield_stress_pa is None and not o.fixed:
            del scene.part_overrides[pid]
    return scene, cloud


def _attributes_changed(a: SplatCloud, b: SplatCloud) -> bool:
    names = ("E", "density", "part_id", "material_id", "nu")
    return any(a.has(n) != b.has(n) or (a.has(n) and not np.array_equal(a.get(n), b.get(n))) for n in names)


def write_model(out_dir: Path, diagnosis: Diagnosis, input_cloud: SplatCloud) -> dict[str, Path]:
    """Write scene.json (always) and model.ply (when material attributes changed)."""
    scene, cloud = bake_material_overrides(diagnosis.scene, diagnosis.cloud)
    paths = {"scene": out_dir / "scene.json"}
    scene.to_json(paths["scene"])
    if _attributes_changed(input_cloud, cloud):
        paths["model"] = out_dir / "model.ply"
        cloud.write(paths["model"])
    return paths


def resimulate_written(paths: dict[str, Path], input_cloud: SplatCloud, tracks: MeasuredTracks,
                       device: str, fill: bool) -> np.ndarray:
    """Simulate the model exactly as written (files read back) → tracked points (T,M,3)."""
    from ..sim.scene import Scene
    from ..splat import read_splat
    from .forward import ForwardModel

    cloud = read_splat(paths["model"]) if "model" in paths else input_cloud
    scene = Scene.from_json(paths["scene"])
    return ForwardModel(cloud, tracks, device=device, fill=fill).simulate_full(scene)


def region_table(tracks: MeasuredTracks, cloud: SplatCloud, before: np.ndarray, after: np.ndarray,
                 clusters: int = 4) -> list[dict]:
    """RMS gap before/after per part and per spatial cluster of the tracked points."""
    vis = tracks.visible
    rb = residuals(tracks.x, before, vis)
    ra = residuals(tracks.x, after, vis)
    labels = {"cluster": spatial_clusters(cloud.means[tracks.ids].astype(np.float64), clusters)}
    if cloud.has("part_id"):
        labels = {"part": cloud.get("part_id")[tracks.ids], **labels}
    rows = []
    for kind, lab in labels.items():
        for key in np.unique(lab):
            sel = lab == key
            rows.append({"kind": kind, "key": int(key), "points": int(sel.sum()),
                         "rms_before": rms_gap(rb[:, sel], vis[:, sel]),
                         "rms_after": rms_gap(ra[:, sel], vis[:, sel])})
    return rows


def summary(diagnosis: Diagnosis, gap_before: float, gap_after: float, regions: list[dict],
            files: dict[str, str], seconds: float | None = None) -> dict:
    """The JSON object `pixie diagnose --json` prints last (plus details for report.json)."""
    first = diagnosis.effect
    ranking = diagnosis.rounds[0].ranking if diagnosis.rounds else []
    return {
        "effect": first.effect if first else None,
        "part": first.part if first else None,
        "params": {k: float(v) for k, v in first.params.items()} if first else {},
        "gap_before": gap_before,
        "gap_after": gap_after,
        "gap_reduction": 1.0 - gap_after / gap_before if gap_before > 0 else 0.0,
        "significant": bool(first),
        "chain": [{"effect": s.effect, "part": s.part, "params": {k: float(v) for k, v in s.params.items()},
                   "delta_bic": s.delta_bic} for s in diagnosis.accepted],
        "ranking": [{"effect": s.effect, "part": s.part, "score": s.delta_bic,
                     "explained": s.explained, "significant": s.significant,
                     "params": {k: float(v) for k, v in s.params.items()}} for s in ranking],
        "noise_sigma": diagnosis.noise_sigma,
        "converged": diagnosis.converged,
        "status": status(diagnosis),
        "ambiguous_with": [{"effect": s.effect, "part": s.part, "score": s.delta_bic,
                            "params": {k: float(v) for k, v in s.params.items()},
                            "separate_by": separation_hint(first.effect, s.effect)}
                           for s in diagnosis.ambiguous] if first else [],
        "floor": diagnosis.floor.to_dict() if diagnosis.floor is not None else None,
        "registration": diagnosis.registration.to_dict() if diagnosis.registration is not None else None,
        "note": effective_note(diagnosis),
        "regions": regions,
        "simulations": diagnosis.runs,
        "simulation_seconds": diagnosis.sim_seconds,
        "seconds": seconds,
        "files": files,
    }


def status(diagnosis: Diagnosis) -> str:
    """One line: what the diagnosis concluded (named / ambiguous / nothing / not converged)."""
    if not diagnosis.converged:
        return diagnosis.floor.message()
    first = diagnosis.effect
    if first is None:
        return "nothing significant is missing: no candidate effect explains the gap beyond noise and solver error"
    if diagnosis.ambiguous:
        others = ", ".join(s.label for s in diagnosis.ambiguous)
        hints = "; ".join(f"{s.label}: {separation_hint(first.effect, s.effect)}" for s in diagnosis.ambiguous)
        return (f"{first.label} fits best but is indistinguishable on these data from {others} "
                f"(to separate them — {hints})")
    return f"missing effect: {first.label}"


def effective_note(diagnosis: Diagnosis) -> str | None:
    """Fitted parameter values are effective for this solver and resolution, not material constants."""
    if diagnosis.effect is None:
        return None
    fl = diagnosis.floor
    where = f" at dx = {100 * fl.dx_m:.3g} cm (grid {fl.grid})" if fl is not None else ""
    return (f"fitted values are effective for this solver{where}: they make this simulation match the "
            "measurement and absorb part of its discretisation error; they are not measured material constants")


def details(diagnosis: Diagnosis) -> dict:
    """Per-round location summaries and full rankings with evidence (for report.json)."""
    t = diagnosis.tracks.t
    return {"rounds": [{"round": r.index, "baseline_rms": r.baseline_rms,
                        "location": r.location.summary(t),
                        "chosen": None if r.chosen is None else r.chosen.to_dict(),
                        "ranking": [s.to_dict() for s in r.ranking], "note": r.note} for r in diagnosis.rounds],
            "parts_from_materials": diagnosis.parts_from_materials}


def plot_gap(path: Path, diagnosis: Diagnosis, after: np.ndarray, regions: list[dict]) -> None:
    """PNG: RMS gap over time before/after, per-region bars, candidate ranking (ΔBIC)."""
    from matplotlib.figure import Figure  # no pyplot: no backend selection or GUI set-up

    tr = diagnosis.tracks
    fb = per_frame_rms(residuals(tr.x, diagnosis.base_pred, tr.visible), tr.visible)
    fa = per_frame_rms(residuals(tr.x, after, tr.visible), tr.visible)
    fig = Figure(figsize=(15, 4.2))
    axes = fig.subplots(1, 3)
    ax = axes[0]
    ax.plot(tr.t, fb, "o-", ms=3, color="tab:red", label="model as given")
    label = " + ".join(s.label for s in diagnosis.accepted) or "no effect added"
    ax.plot(tr.t, fa, "o-", ms=3, color="tab:green", label=f"with {label}")
    ax.axhline(np.sqrt(3) * diagnosis.noise_sigma, color="grey", ls="--", lw=1, label="tracking noise")
    if diagnosis.floor is not None and diagnosis.floor.enabled:
        ax.axhline(diagnosis.floor.rms, color="tab:purple", ls=":", lw=1.2,
                   label=f"solver-error floor (grid {diagnosis.floor.grid})")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("RMS gap (splat units)")
    ax.set_title("where in time")
    ax.legend(fontsize=8)
    ax = axes[1]
    names = [f"{r['kind']} {r['key']}" for r in regions]
    pos = np.arange(len(regions))
    ax.bar(pos - 0.2, [r["rms_before"] for r in regions], 0.4, color="tab:red", label="before")
    ax.bar(pos + 0.2, [r["rms_after"] for r in regions], 0.4, color="tab:green", label="after")
    ax.set_xticks(pos, names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("RMS gap (splat units)")
    ax.set_title("where in space")
    ax.legend(fontsize=8)
    ax = axes[2]
    ranking = diagnosis.rounds[0].ranking[:8] if diagnosis.rounds else []
    scores = [max(s.delta_bic, 0.0) for s in ranking]
    chosen = diagnosis.rounds[0].chosen
    colors = ["tab:green" if chosen is not None and (s.effect, s.part) == (chosen.effect, chosen.part)
              else "yellowgreen" if s.significant else "tab:grey" for s in ranking]
    ax.barh(np.arange(len(ranking))[::-1], scores, color=colors)
    ax.set_yticks(np.arange(len(ranking))[::-1], [s.label for s in ranking], fontsize=8)
    ax.set_xlabel("ΔBIC vs the model as given")
    ax.set_title("which effect (green: chosen, light: significant alone)", fontsize=10)
    if scores and max(scores) > 100:
        ax.set_xscale("symlog")
    if not ranking:
        ax.set_axis_off()
        why = "not converged: the gap is solver error,\nno effect was fitted" if not diagnosis.converged \
            else "no candidate effect was fitted"
        ax.text(0.5, 0.5, why, ha="center", va="center", transform=ax.transAxes, fontsize=10)
    # fixed margins (room for rotated region names and effect labels such as "plastic_yield[part 12]"):
    # tight_layout would draw the figure once more only to measure them (~40 % of the PNG's time)
    fig.subplots_adjust(left=0.045, right=0.99, bottom=0.2, top=0.92, wspace=0.42)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")  # Agg, chosen by the format


PLOT_MODULES = ("matplotlib.figure", "matplotlib.backends.backend_agg")


def prefetch_plotting() -> None:
    """Start importing what plot_gap needs in the background (prefetch.py): a caller that will
    write the PNG after a diagnosis calls this before it, so the import overlaps the simulations
    (the fit itself imports nothing heavy: no scipy, lsq.py and kmeans.py)."""
    from ..prefetch import prefetch

    prefetch(*PLOT_MODULES)


def record(path: Path, diagnosis: Diagnosis, after: np.ndarray) -> None:
    """Rerun recording: measured (white), simulated before (red) and after (green) tracked
    points on the time line, plus the RMS gap before/after as time series."""
    from ..viz import log_scalar, log_splat, recording, send_layout

    tr = diagnosis.tracks
    vis = tr.visible
    fb = per_frame_rms(residuals(tr.x, diagnosis.base_pred, vis), vis)
    fa = per_frame_rms(residuals(tr.x, after, vis), vis)
    span = float(np.nanmax(np.ptp(np.nan_to_num(tr.x.reshape(-1, 3)), axis=0))) or 1.0
    radius = 0.006 * span
    colours = {"measured": (240, 240, 240), "simulated_before": (220, 60, 60), "simulated_after": (60, 200, 90)}
    with recording("pixie-diagnose", path) as rec:
        for name, rgb in colours.items():
            log_splat(rec, f"tracks/{name}", np.zeros((tr.num_points, 3), np.float32),
                      rgb=np.tile(np.array(rgb, np.uint8), (tr.num_points, 1)), radii=radius, time_s=None)
        for i, t in enumerate(tr.t):
            meas = np.where(vis[i][:, None], np.nan_to_num(tr.x[i]), np.nan)
            log_splat(rec, "tracks/measured", meas[vis[i]] if not vis[i].all() else meas, time_s=float(t))
            log_splat(rec, "tracks/simulated_before", diagnosis.base_pred[i], time_s=float(t))
            log_splat(rec, "tracks/simulated_after", after[i], time_s=float(t))
            log_scalar(rec, "gap/before", float(fb[i]), time_s=float(t))
            log_scalar(rec, "gap/after", float(fa[i]), time_s=float(t))
        send_layout(rec, entities=["tracks"], names=["measured (white) vs simulated before (red) / after (green)"],
                    plots=["gap"])


def write_report(out_dir: Path, diagnosis: Diagnosis, input_cloud: SplatCloud, device: str = "auto",
                 fill: bool = False, resimulate: bool = False, rrd: bool = True, png: bool = True,
                 seconds: float | None = None) -> dict:
    """Write every output into `out_dir` (which must exist) and return the summary dict.

    The gap "after" comes from the full-model re-simulation of the improved model that the
    diagnosis already ran; `resimulate` runs it once more from the files as written (a check
    that the baked `.ply` + scene.json reproduce it)."""
    paths = write_model(out_dir, diagnosis, input_cloud)
    if resimulate and diagnosis.accepted:
        after = resimulate_written(paths, input_cloud, diagnosis.tracks, device, fill)
    else:
        after = diagnosis.final_pred
    tr = diagnosis.tracks
    gap_before = rms_gap(residuals(tr.x, diagnosis.base_pred, tr.visible), tr.visible)
    gap_after = rms_gap(residuals(tr.x, after, tr.visible), tr.visible)
    regions = region_table(tr, diagnosis.cloud, diagnosis.base_pred, after)
    files = {k: v.name for k, v in paths.items()}  # names inside out_dir
    if png:
        files["plot"] = "gap.png"
        plot_gap(out_dir / "gap.png", diagnosis, after, regions)
    if rrd:
        files["recording"] = "diagnose.rrd"
        record(out_dir / "diagnose.rrd", diagnosis, after)
    files["report"] = "report.json"
    result = summary(diagnosis, gap_before, gap_after, regions, files, seconds)
    with atomic_path(out_dir / "report.json", suffix=".json") as tmp:
        tmp.write_text(json.dumps({**result, **details(diagnosis)}, indent=2, default=_json_default) + "\n",
                       encoding="utf-8")
    return result


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
