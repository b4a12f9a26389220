"""Rubber duck drop: the shipped duck, materials predicted (soft elastic), falls 15 cm onto the
ground, squashes on impact and bounces back up.

    python examples/duck_drop.py --out examples_out/duck_drop
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402

SCENE = {
    "up": "z",
    "object": {"size_m": 0.17, "position": [0.0, 0.0, 0.15]},  # bottom of the duck 15 cm above ground
    "domain": {"size_m": 0.5},
    "gravity": [0.0, 0.0, -9.81],
    "ground": {"enabled": True, "height_m": 0.0, "friction": 0.3},
    "damping": 0.0,
}
FULL = _common.Size(frames=36, fps=40.0, grid=40, particles_per_cell=4)
TINY = _common.Size(frames=22, fps=40.0, grid=24, particles_per_cell=2)


def main(argv: list[str] | None = None) -> dict:
    import numpy as np

    args = _common.parser(__doc__, "duck_drop").parse_args(argv)
    out = _common.setup(args)
    cloud = _common.annotated_example("duck", args, out)
    result = _common.simulate(cloud, SCENE, TINY if args.tiny else FULL, args, out, "duck_drop",
                              fill=True, elevation_deg=5.0)
    x = result.x_world
    bottom = x[:, :, 2].min(axis=1)  # lowest Gaussian (m) per frame
    centre = x[:, :, 2].mean(axis=1)  # mean height (m) per frame
    falling = np.flatnonzero((centre[1:-1] < centre[:-2]) & (centre[1:-1] <= centre[2:])) + 1
    low = int(falling[0]) if len(falling) else len(centre) - 1  # first frame of the impact's lowest point
    rebound = float(centre[low:].max() - centre[low])
    return _common.report("duck_drop", out, result, {
        "start_centre_height_m": float(centre[0]),
        "lowest_centre_frame": low,
        "lowest_centre_height_m": float(centre[low]),
        "bottom_at_impact_m": float(bottom[low]),
        "rebound_height_m": rebound,
        "bounced": bool(rebound > 0.005 and bottom[low] < 0.05),
    })


if __name__ == "__main__":
    _common.run_cli(main)
