"""Benchmark of `pixie diagnose` on tracks from an INDEPENDENT engine (a Taichi MLS-MPM, not
pixie-gs's solver): does it name the hidden effect, stay silent when nothing is hidden, refuse
solver error and wrong units, and survive a clock offset, outlier tracks and occlusion?

    python benchmarks/bench_diagnose_independent.py            # all cases (CPU)
    python benchmarks/bench_diagnose_independent.py --only nothing,air_drag

Fixtures: tests/data/independent/*.npz (scripts/make_independent_tracks.py; README there): the
two-part jelly tossed onto the ground, one hidden effect each, 100 tracked points (5 % of the
model's 2000 Gaussians) with 1 mm noise, 17 frames at 25 fps, no ids. The model is the plain
two_part_block(2000, seed=0) in `independent_toss_scene(grid)`; diagnose runs with every check
on (units, registration, offset, outliers, solver-error floor). Corruptions (mm, one frame off,
5 % outlier tracks, 20 % occlusion) are applied here, deterministically.
A case passes when the hidden effect (and part) is named first or listed in ambiguous_with;
for "nothing hidden" when no effect is named; for mm tracks when diagnose refuses them.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pixie_gs.diagnose.measured import tracks_from_arrays  # noqa: E402
from pixie_gs.diagnose.pipeline import DiagnoseOptions, diagnose  # noqa: E402
from pixie_gs.diagnose.synthetic import (add_outlier_tracks, in_millimetres, independent_toss_scene,  # noqa: E402
                                         occlude, start_late, two_part_block)
from pixie_gs.errors import InputError  # noqa: E402
from pixie_gs.progress import set_quiet  # noqa: E402

DATA = ROOT / "tests" / "data" / "independent"
FINE, COARSE = 80, 40     # dx 2.5 cm and 5 cm in the 2 m domain

# name, fixture, hidden (effect, part), grid, corruption, units
CASES = [
    ("nothing hidden", "nothing", (None, None), FINE, None, None),
    ("viscous damping", "viscous_damping", ("viscous_damping", None), FINE, None, None),
    ("air drag", "air_drag", ("air_drag", None), FINE, None, None),
    ("ground friction", "ground_friction", ("ground_friction", None), FINE, None, None),
    ("wind", "wind", ("wind", None), FINE, None, None),
    ("head 5x softer", "part_stiffness", ("part_stiffness", 1), FINE, None, None),
    ("body 5x softer", "part_stiffness_body", ("part_stiffness", 0), FINE, None, None),
    ("head 4x heavier", "part_density", ("part_density", 1), FINE, None, None),
    ("body yields", "plastic_yield", ("plastic_yield", 0), FINE, None, None),
    ("body anchored", "anchored_part", ("anchored_part", 0), FINE, None, None),
    ("nothing, coarse grid", "nothing", (None, None), COARSE, None, None),
    ("drag, tracks in mm", "air_drag", ("refused", None), FINE, "mm", None),
    ("drag, mm + --units mm", "air_drag", ("air_drag", None), FINE, "mm", "mm"),
    ("friction, one frame off", "ground_friction", ("ground_friction", None), FINE, "late", None),
    ("density, 5% outlier tracks", "part_density", ("part_density", 1), FINE, "outliers", None),
    ("wind, 20% occlusion", "wind", ("wind", None), FINE, "occlusion", None),
]


def label(effect: str | None, part: int | None) -> str:
    return "nothing" if effect is None else (effect if part is None else f"{effect}[{part}]")


def load_case(fixture: str, corruption: str | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list]:
    with np.load(DATA / f"{fixture}.npz") as data:
        t, x = data["t"].astype(np.float64), data["x"].astype(np.float64)
    visible, bad = None, []
    if corruption == "mm":
        x = in_millimetres(x)
    elif corruption == "late":
        t, x = start_late(t, x, frames=1, seed=5)
    elif corruption == "outliers":
        x, bad = add_outlier_tracks(x, 0.05, seed=6)
    elif corruption == "occlusion":
        visible = occlude(x, 0.2, seed=7)
        x = np.where(visible[:, :, None], x, np.nan)
    return t, x, visible, list(bad)


def run_case(cloud, case) -> dict:
    name, fixture, (effect, part), grid, corruption, units = case
    t, x, visible, bad = load_case(fixture, corruption)
    start = time.perf_counter()
    row = {"case": name, "hidden": label(effect, part) if effect != "refused" else "mm (refuse)", "grid": grid}
    try:
        tracks = tracks_from_arrays(t, x, cloud, visible=visible, source=f"{fixture}.npz")
        d = diagnose(cloud, independent_toss_scene(grid), tracks, device="cpu",
                     options=DiagnoseOptions(units=units))
    except InputError as exc:
        row.update(named="REFUSED", ambiguous=[], ok=effect == "refused", seconds=time.perf_counter() - start,
                   note=str(exc).split(": ", 1)[-1][:90], floor=float("nan"), gap=float("nan"), runs=0)
        return row
    named = d.effect
    amb = [label(s.effect, s.part) for s in d.ambiguous]
    target = label(effect, part)
    if effect is None:
        ok = named is None
    else:
        ok = named is not None and (label(named.effect, named.part) == target or target in amb)
    reg = d.registration
    notes = []
    if not d.converged:
        notes.append("not converged")
    if reg is not None and reg.time_offset_applied:
        notes.append(f"offset {reg.time_offset_s * 25:+.2f} fr")
    if reg is not None and reg.outliers:
        found = {o["track"] for o in reg.outliers}
        notes.append(f"outliers {len(found & set(bad))}/{len(bad)} found, {len(found - set(bad))} false")
    if units:
        notes.append(f"units ×{reg.units_factor:g}")
    if named is not None and named.params:
        notes.insert(0, ", ".join(f"{k}={v:.3g}" for k, v in named.params.items()))
    mm = 1000.0 * (d.floor.world_scale if d.floor else 1.5)
    row.update(named=label(named.effect, named.part) if named else "nothing", ambiguous=amb, ok=ok,
               seconds=time.perf_counter() - start, runs=d.runs, note="; ".join(notes),
               floor=mm * (d.floor.rms if d.floor else 0.0), gap=mm * d.gap_before,
               gap_after=mm * d.gap_after)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="comma-separated fixture names (default: every case)")
    args = ap.parse_args()
    set_quiet(True)
    cloud = two_part_block(n=2000, seed=0)
    cases = [c for c in CASES if not args.only or c[1] in args.only.split(",")]
    rows = []
    print(f"{'case':28s} {'hidden':22s} {'grid':>4s} {'named first':22s} {'ambiguous_with':34s} "
          f"{'floor mm':>8s} {'gap mm':>7s} {'sims':>4s} {'s':>6s}  ok  notes")
    for case in cases:
        r = run_case(cloud, case)
        rows.append(r)
        print(f"{r['case']:28s} {r['hidden']:22s} {r['grid']:4d} {r['named']:22s} {','.join(r['ambiguous']) or '-':34s} "
              f"{r['floor']:8.1f} {r['gap']:7.1f} {r['runs']:4d} {r['seconds']:6.1f}  {'ok ' if r['ok'] else 'NO '} "
              f"{r['note']}", flush=True)
    effect_rows = [r for r in rows if r["hidden"] not in ("nothing", "mm (refuse)")]
    print(f"\nhidden effect named first or in ambiguous_with: {sum(r['ok'] for r in effect_rows)}/{len(effect_rows)}; "
          f"'nothing hidden' naming an effect: {sum(not r['ok'] for r in rows if r['hidden'] == 'nothing')}; "
          f"mm tracks passing silently: {sum(not r['ok'] for r in rows if r['hidden'] == 'mm (refuse)')}; "
          f"all cases ok: {sum(r['ok'] for r in rows)}/{len(rows)}; runtime per case: median "
          f"{np.median([r['seconds'] for r in rows]):.0f} s, max {max(r['seconds'] for r in rows):.0f} s")


if __name__ == "__main__":
    main()
