"""Shared plumbing of the example scripts: flags, the annotated example splat, the run, the report.

Every example takes `--out DIR`, `--tiny` (the CI size: seconds on a CPU), `--device`, `--seed`,
`--labels predicted|true` (materials from the shipped checkpoint, or the generator's ground truth)
and `--checkpoint`. The work itself is done by the library (pixie_gs.annotate, pixie_gs.sim,
pixie_gs.demo.run_scenario); this file only wires it up and prints what was written.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

@dataclass
class Size:
    """How big a run is: output frames at fps, grid cells per domain side, Gaussians per cell."""

    frames: int
    fps: float
    grid: int
    particles_per_cell: int


def parser(doc: str, name: str) -> argparse.ArgumentParser:
    """The flags every example shares; `doc` is the script's docstring (its --help text)."""
    from pixie_gs.devices import DEVICE_CHOICES

    p = argparse.ArgumentParser(prog=f"{name}.py", description=doc,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=str(Path("examples_out") / name), metavar="DIR",
                   help=f"output directory (default examples_out/{name})")
    p.add_argument("--tiny", action="store_true", help="CI size: few particles and frames (seconds on a CPU)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="auto", help="torch/Warp device")
    p.add_argument("--seed", type=int, default=0, help="seed of the per-cell particle choice")
    p.add_argument("--labels", choices=("predicted", "true"), default="predicted",
                   help="materials from the shipped checkpoint (predicted) or the generator's ground truth")
    p.add_argument("--checkpoint", default=None, help="material model checkpoint (default: the shipped one)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars or stage lines")
    return p


def setup(args: argparse.Namespace) -> Path:
    """Apply --quiet and create the output directory."""
    from pixie_gs.demo import prepare_out_dir
    from pixie_gs.progress import set_quiet

    set_quiet(args.quiet)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    return prepare_out_dir(args.out)


def annotated_example(name: str, args: argparse.Namespace, out_dir: Path):
    """The shipped example splat `name` with materials (predicted or true), written to
    out_dir/annotated.ply."""
    from pixie_gs.demo import example_path, material_summary
    from pixie_gs.progress import stage

    if args.labels == "true":
        from pixie_gs.dataset.examples import build_example

        cloud, _ = build_example(name)
    else:
        from pixie_gs.annotate import annotate_cloud
        from pixie_gs.splat import read_splat

        cloud = annotate_cloud(read_splat(example_path(name)), checkpoint=args.checkpoint,
                               device=args.device, up="z")
    cloud.write(out_dir / "annotated.ply")
    stage(f"{name}: {args.labels} materials " + ", ".join(f"{k} {v}" for k, v in material_summary(cloud).items()))
    return cloud


def stretch_vertically(cloud, factor: float):
    """A copy of `cloud` stretched by `factor` along z: centres, and covariances Σ' = SΣS."""
    out = cloud.copy()
    S = np.diag([1.0, 1.0, factor])
    cov = out.covariances()
    out.means = (out.means * np.array([1.0, 1.0, factor], np.float32)).astype(np.float32)
    out.set_covariances(S @ cov @ S)
    return out


def simulate(cloud, scene_dict: dict, size: Size, args: argparse.Namespace, out_dir: Path, name: str,
             fill: bool = False, **view):
    """Run `scene_dict` (docs/scene.md keys; domain.grid from `size`) and write everything under
    out_dir; returns pixie_gs.demo.ScenarioResult."""
    from pixie_gs.demo import run_scenario
    from pixie_gs.sim.scene import Scene

    scene_dict = json.loads(json.dumps(scene_dict))
    scene_dict.setdefault("domain", {})["grid"] = size.grid
    scene = Scene.from_dict(scene_dict, source=f"{name} scene")
    scene.to_json(out_dir / "scene.json")
    return run_scenario(cloud, scene, out_dir, size.frames, size.fps, device=args.device,
                        particles_per_cell=size.particles_per_cell, seed=args.seed, fill=fill,
                        app_id=f"pixie-{name}", gif=not args.tiny, **view)


def report(name: str, out_dir: Path, result, facts: dict) -> dict:
    """Print what was written and the measured facts; write them to out_dir/summary.json."""
    facts = {k: (round(float(v), 6) if isinstance(v, (float, np.floating)) else v) for k, v in facts.items()}
    facts["simulated_gaussians"] = len(result.cloud)
    facts["frames"] = len(result.traj.t)
    facts["seconds"] = {k: round(v, 2) for k, v in result.seconds.items()}
    summary = out_dir / "summary.json"
    summary.write_text(json.dumps(facts, indent=1) + "\n")
    print(f"{name}: wrote")
    for path in [*sorted(p for p in out_dir.glob("*.ply")), out_dir / "scene.json", *result.files.values(), summary]:
        print(f"  {path}")
    for key, value in facts.items():
        print(f"  {key}: {value}")
    sys.stdout.flush()
    return facts


def run_cli(main) -> None:
    """Run an example's `main()` as a script: pixie errors become one line and an exit code."""
    from pixie_gs.errors import PixieError

    try:
        main()
    except PixieError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
