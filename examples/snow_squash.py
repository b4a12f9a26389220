"""Snow-and-mud lump squashing: the shipped snow/mud pile, materials predicted (snow:
elasto-plastic with hardening), heaped into a lump (stretched ×3 in height) and dropped 40 cm
onto the ground; it squashes (compacts plastically) and stays squashed instead of bouncing
back like an elastic body.

    python examples/snow_squash.py --out examples_out/snow_squash
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402

LUMP_STRETCH = 3.0
SCENE = {
    "up": "z",
    "object": {"size_m": 0.4, "position": [0.0, 0.0, 0.4]},  # lump bottom 40 cm above the ground
    "domain": {"size_m": [1.2, 1.2, 1.0]},
    "gravity": [0.0, 0.0, -9.81],
    "ground": {"enabled": True, "height_m": 0.0, "friction": 0.6},
    # compacted snow hardens (stiffness × e^{ξ(1−Jp)}), so its waves outrun a dt set from the
    # initial stiffness: a smaller CFL fraction keeps the impact stable
    "solver": {"max_substeps_per_frame": 400, "cfl": 0.1},
}
FULL = _common.Size(frames=25, fps=30.0, grid=48, particles_per_cell=3)
TINY = _common.Size(frames=17, fps=30.0, grid=32, particles_per_cell=2)


def main(argv: list[str] | None = None) -> dict:
    import numpy as np

    args = _common.parser(__doc__, "snow_squash").parse_args(argv)
    out = _common.setup(args)
    cloud = _common.stretch_vertically(_common.annotated_example("snow", args, out), LUMP_STRETCH)
    result = _common.simulate(cloud, SCENE, TINY if args.tiny else FULL, args, out, "snow_squash",
                              elevation_deg=10.0)
    x = result.x_world
    height = np.quantile(x[:, :, 2], 0.98, axis=1) - x[:, :, 2].min(axis=1)
    width = np.quantile(x[:, :, 0], 0.98, axis=1) - np.quantile(x[:, :, 0], 0.02, axis=1)
    landed = x[-1, :, 2].min() < 0.05
    return _common.report("snow_squash", out, result, {
        "height_before_m": float(height[0]),
        "height_min_m": float(height.min()),
        "height_after_m": float(height[-1]),
        "width_before_m": float(width[0]),
        "width_after_m": float(width[-1]),
        "landed": bool(landed),
        "squashed": bool(landed and height[-1] < 0.8 * height[0]),
    })


if __name__ == "__main__":
    _common.run_cli(main)
