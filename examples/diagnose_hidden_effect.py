"""Worked example of `pixie diagnose`: hide a physical effect from a model, measure, diagnose.

    python examples/diagnose_hidden_effect.py [OUT_DIR] [--effect ground_friction] [--device cpu]

1. Build a small two-part jelly object (model.ply) and a scene that tosses it (scene.json).
2. Make the TRUE world: the same model with one effect of the library added (default: the
   ground is much grippier, μ 0.3 → 1.5), written as true_scene.json / true_model.ply.
3. `pixie simulate` the true world → tracks.npz; keep 5 % of the tracks, add 1 mm of noise and
   drop the Gaussian ids → measured.npz (what a point tracker on a video would give).
4. `pixie diagnose model.ply measured.npz --scene scene.json --out diag/` starts from the plain
   model and must name the hidden effect, fit its parameter and shrink the gap.
Prints the diagnosis; diag/gap.png and diag/diagnose.rrd show it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pixie_gs.cli.main import main as pixie  # noqa: E402
from pixie_gs.diagnose.measured import save_measured  # noqa: E402
from pixie_gs.diagnose.synthetic import HIDDEN_EFFECTS, hide_effect, toss_scene, track_subset, two_part_block  # noqa: E402


def run(argv: list[str]) -> int:
    code = pixie(argv)
    if code != 0:
        raise SystemExit(f"pixie {argv[0]} failed with exit code {code}")
    return code


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default="diagnose_example", help="output directory")
    ap.add_argument("--effect", default="ground_friction", choices=[h[0] for h in HIDDEN_EFFECTS],
                    help="the effect hidden from the model (strong setting of the test catalogue)")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    # 1. the model as the user has it
    cloud = two_part_block(n=1000, seed=0)
    scene = toss_scene()
    cloud.write(out / "model.ply")
    scene.to_json(out / "scene.json")

    # 2. the true world: the model plus one effect it lacks
    effect, part, _, strong = next(h for h in HIDDEN_EFFECTS if h[0] == args.effect)
    if args.effect == "ground_friction":
        strong = {"mu": 1.5}
    true_scene, true_cloud = hide_effect(scene, cloud, effect, part, strong)
    true_scene.to_json(out / "true_scene.json")
    true_cloud.write(out / "true_model.ply")
    print(f"hidden from the model: {effect}" + (f" of part {part}" if part is not None else "") + f" {strong}")

    # 3. "measure" it: simulate the true world, track 5 % of the points with 1 mm noise
    run(["simulate", str(out / "true_model.ply"), "--scene", str(out / "true_scene.json"),
         "--out", str(out / "true_frames"), "--frames", "17", "--fps", "25", "--device", args.device,
         "--force", "--quiet"])
    with np.load(out / "true_frames" / "tracks.npz") as tracks:
        t, x = tracks["t"], tracks["x"]
    _, measured = track_subset(x, fraction=0.05, noise_m=1e-3, seed=1)
    save_measured(out / "measured.npz", t, measured)  # no ids: matched to Gaussians at t0
    print(f"measured {measured.shape[1]} of {x.shape[1]} points over {len(t)} frames")

    # 4. diagnose from the plain model (--no-floor: this "measurement" is pixie's own solver at the
    # same grid, so it has no solver error; real tracks keep the floor on, docs/diagnose.md)
    run(["diagnose", str(out / "model.ply"), str(out / "measured.npz"), "--scene", str(out / "scene.json"),
         "--out", str(out / "diag"), "--device", args.device, "--force", "--no-floor"])
    print(f"see {out / 'diag' / 'gap.png'} and {out / 'diag' / 'diagnose.rrd'}")


if __name__ == "__main__":
    main()
