"""`pixie diagnose MODEL.ply MEASURED.npz --scene SCENE.json --out DIR`: name the missing effect."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..devices import DEVICE_CHOICES, DEVICE_HELP
from ..errors import InputError
from .options import add_drop_invalid_option


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "diagnose", parents=parents,
        help="find what physical effect a simulation is missing versus measured tracks",
        description="Compare the simulated model (annotated splat + scene) with measured point tracks "
        "(.npz: t (T,) s, x (T,M,3), optional ids (M,), visible (T,M)); locate where and when they disagree; "
        "fit every candidate effect of the library (damping, air drag, ground friction, plastic yield, wind, "
        "a part's stiffness/density, an anchored part) and rank them by BIC; add the winner, re-simulate and "
        "show the gap before/after. Writes DIR/scene.json, DIR/model.ply (material effects), DIR/report.json, "
        "DIR/gap.png and DIR/diagnose.rrd.",
        epilog="example: pixie diagnose model.ply measured.npz --scene scene.json --out diag/ --json",
    )
    p.add_argument("model", metavar="MODEL.ply", nargs="?",
                   help="annotated 3D Gaussian splat (material_id, E, nu, density)")
    p.add_argument("measured", metavar="MEASURED.npz", nargs="?",
                   help="measured tracks: t (T,), x (T,M,3) [, ids, visible]")
    p.add_argument("--scene", metavar="SCENE.json", help="scene the model was simulated in (default: drop preset)")
    p.add_argument("--out", metavar="DIR", help="output directory (created if missing; required)")
    p.add_argument("--effects", metavar="A,B", help="only test these effects (default: the whole library; "
                   "`--effects list` prints it)")
    p.add_argument("--max-effects", type=int, default=2, metavar="K", help="add at most K effects in a chain (2)")
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line of stdout")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help=DEVICE_HELP)
    p.add_argument("--fill", action="store_true", help="fill solid interiors (as `pixie simulate --fill`)")
    p.add_argument("--max-particles", type=int, default=3000, metavar="N",
                   help="fit on a reduced model of at most N Gaussians (coarser grid), delta-corrected (3000)")
    p.add_argument("--max-evals", type=int, default=10, metavar="N", help="simulations per candidate effect (10)")
    p.add_argument("--units", choices=("mm", "cm", "m"),
                   help="unit of MEASURED.npz's coordinates when the splat's are metres (default: the splat's own)")
    p.add_argument("--grid", type=int, metavar="N",
                   help="simulate on N cells along the domain's longest side (overrides the scene's domain.grid)")
    p.add_argument("--no-floor", action="store_true",
                   help="skip the solver-error floor (only for tracks made by this very solver at this grid)")
    p.add_argument("--no-checks", action="store_true",
                   help="skip registration, start-time offset and outlier-track checks")
    p.add_argument("--no-rrd", action="store_true", help="skip the rerun recording")
    p.add_argument("--verify-written", action="store_true",
                   help="re-simulate the improved model once more from the files written to DIR")
    p.add_argument("--force", action="store_true", help="overwrite an earlier diagnosis in DIR")
    add_drop_invalid_option(p)
    p.set_defaults(func=run)
    return p


OUTPUT_NAMES = ("scene.json", "model.ply", "report.json", "gap.png", "diagnose.rrd")


def run(args: argparse.Namespace) -> int:
    import json
    import shutil
    import tempfile
    import time

    from ..diagnose.effects import effect_names, registry
    from ..diagnose.forward import Fidelity
    from ..diagnose.measured import load_measured
    from ..diagnose.pipeline import DiagnoseOptions, diagnose
    from ..diagnose.report import prefetch_plotting, write_report
    from ..progress import stage
    from ..sim.run import _material_arrays
    from ..sim.scene import Scene
    from ..splat import read_splat_valid

    if args.effects == "list":
        for effect in registry().values():
            print(f"{effect.name:16s} {effect.doc}")
        return 0
    if not args.model or not args.measured or not args.out:
        import sys

        print("pixie diagnose: error: MODEL.ply, MEASURED.npz and --out DIR are required "
              "(see `pixie diagnose --help`)", file=sys.stderr)
        return 2  # a usage error, like argparse's
    effects = None
    if args.effects:
        effects = [e.strip() for e in args.effects.split(",") if e.strip()]
        unknown = [e for e in effects if e not in effect_names()]
        if unknown:
            raise InputError(f"--effects: unknown effect '{unknown[0]}' (known: {', '.join(effect_names())})")
    if args.max_effects < 1:
        raise InputError(f"--max-effects must be ≥ 1, got {args.max_effects}")
    if args.max_particles < 100:
        raise InputError(f"--max-particles must be ≥ 100, got {args.max_particles}")
    if args.max_evals < 2:
        raise InputError(f"--max-evals must be ≥ 2, got {args.max_evals}")
    start = time.perf_counter()
    cloud = read_splat_valid(args.model, args.drop_invalid)
    _material_arrays(cloud)
    scene = Scene.from_json(args.scene) if args.scene else Scene.preset("drop")
    if args.grid is not None:
        if args.grid < 8:
            raise InputError(f"--grid must be ≥ 8, got {args.grid}")
        scene.domain.grid = args.grid
    tracks = load_measured(args.measured, cloud)
    if not args.no_checks:  # units, registration and match distances: fail before any output exists
        from ..diagnose.checks import check_geometry
        from ..diagnose.pipeline import working_cloud

        check_geometry(tracks, working_cloud(cloud)[0], args.units)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a directory", out)
    if out.is_dir() and not args.force:
        clash = [n for n in OUTPUT_NAMES if (out / n).exists()]
        if clash:
            raise InputError(f"already holds a diagnosis ({clash[0]}); use --force to overwrite", out)
    out.mkdir(parents=True, exist_ok=True)
    options = DiagnoseOptions(effects=effects, max_effects=args.max_effects, max_evals=args.max_evals,
                              fidelity=Fidelity(max_particles=args.max_particles), fill=args.fill,
                              checks=not args.no_checks, units=args.units, solver_floor=not args.no_floor)
    stage(f"diagnosing {args.model} against {tracks.num_points} tracked points × {tracks.num_frames} frames")
    prefetch_plotting()  # the PNG's imports overlap the diagnosis
    result_diag = diagnose(cloud, scene, tracks, device=args.device, options=options)
    # write everything into a private folder first, then move the finished files into DIR
    staging = Path(tempfile.mkdtemp(prefix=".diagnose.", dir=out))
    try:
        summary = write_report(staging, result_diag, cloud, device=args.device, fill=args.fill,
                               resimulate=args.verify_written, rrd=not args.no_rrd, seconds=None)
        summary["seconds"] = time.perf_counter() - start
        report = json.loads((staging / "report.json").read_text(encoding="utf-8"))
        report["seconds"] = summary["seconds"]
        (staging / "report.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
        for name in OUTPUT_NAMES:
            if (staging / name).exists():
                (staging / name).replace(out / name)
            elif args.force and (out / name).exists():
                (out / name).unlink()  # a stale file from an earlier diagnosis
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    summary["files"] = {k: str(out / v) for k, v in summary["files"].items()}
    if args.json:
        print(json.dumps({k: summary[k] for k in ("effect", "part", "params", "gap_before", "gap_after",
                                                  "gap_reduction", "ranking", "chain", "noise_sigma",
                                                  "converged", "status", "ambiguous_with", "floor",
                                                  "registration", "note", "simulations", "seconds", "files")}))
    else:
        print_summary(summary)
    return 0


def print_summary(s: dict) -> None:
    """Human-readable result on stdout."""
    for w in (s.get("registration") or {}).get("warnings", []):
        print(f"check: {w}")
    if not s["converged"]:
        print(s["status"])
    elif s["effect"] is None:
        print("nothing significant is missing: no candidate effect explains the gap beyond tracking noise "
              "and solver error")
    for i, step in enumerate(s["chain"], 1):
        part = f" of part {step['part']}" if step["part"] is not None else ""
        params = ", ".join(f"{k}={v:.4g}" for k, v in step["params"].items())
        print(f"missing effect {i}: {step['effect']}{part} ({params}); ΔBIC {step['delta_bic']:.1f}")
    if s["ambiguous_with"]:
        print(s["status"])
    fl = s.get("floor")
    floor = f"; solver-error floor {fl['rms']:.3g} (grid {fl['grid']} vs {fl['fine_grid']}, {fl['coarse_grid']})" \
        if fl and fl["enabled"] else ""
    print(f"RMS gap {s['gap_before']:.4g} → {s['gap_after']:.4g} "
          f"({100 * s['gap_reduction']:.0f}% smaller); tracking noise σ ≈ {s['noise_sigma']:.2g}{floor}")
    if s.get("note"):
        print(f"note: {s['note']}")
    if s["ranking"]:
        print("ranking (round 1, ΔBIC vs the model as given):")
    for r in s["ranking"]:
        part = f"[part {r['part']}]" if r["part"] is not None else ""
        print(f"  {r['effect'] + part:28s} {r['score']:10.1f}  explains {100 * r['explained']:5.1f}%"
              + ("  *" if r["significant"] else ""))
    print(f"{s['simulations']} simulations, {s['seconds']:.0f} s; outputs in "
          f"{Path(s['files']['report']).parent}")
