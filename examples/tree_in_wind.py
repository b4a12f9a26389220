"""Tree in wind: the shipped potted tree, materials predicted, bends downwind in a gust and
swings back while its pot (stationary material, base anchored) stays fixed.

The scene is the demo's (pixie_gs.demo.DEMO_SCENE: a 1 m tree under gravity, a gust along +x
for 0.8 s; pixie_gs/demo.py says why the tree stands).

    python examples/tree_in_wind.py --out examples_out/tree_in_wind
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402

FULL = _common.Size(frames=45, fps=15.0, grid=32, particles_per_cell=6)
TINY = _common.Size(frames=10, fps=15.0, grid=32, particles_per_cell=3)


def main(argv: list[str] | None = None) -> dict:
    import numpy as np

    from pixie_gs.demo import ANCHORED_BASE_M, DEMO_SCENE
    from pixie_gs.materials import STATIONARY

    args = _common.parser(__doc__, "tree_in_wind").parse_args(argv)
    out = _common.setup(args)
    cloud = _common.annotated_example("tree", args, out)
    result = _common.simulate(cloud, DEMO_SCENE, TINY if args.tiny else FULL, args, out, "tree_in_wind")
    sim, x = result.cloud, result.x_world
    z = x[0, :, 2]
    height = float(z.max() - z.min())
    top = z >= np.quantile(z, 0.9)
    anchored = (sim.get("material_id") == STATIONARY) | (z - z.min() <= ANCHORED_BASE_M)
    top_dx = x[:, top, 0].mean(axis=1) - x[0, top, 0].mean()
    return _common.report("tree_in_wind", out, result, {
        "tree_height_m": height,
        "top_max_downwind_m": float(top_dx.max()),
        "top_downwind_last_m": float(top_dx[-1]),
        "top_sink_last_m": float(x[0, top, 2].mean() - x[-1, top, 2].mean()),
        "anchored_gaussians": int(anchored.sum()),
        "anchored_max_motion_m": float(np.abs(x[:, anchored] - x[0, anchored]).max()) if anchored.any() else 0.0,
    })


if __name__ == "__main__":
    _common.run_cli(main)
