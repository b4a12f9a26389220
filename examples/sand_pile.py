"""Sand pile collapse: the shipped sand pile, materials predicted (Drucker–Prager sand), heaped
up steeper than its angle of repose (the splat is stretched ×4 in height), slumps under gravity
and spreads wider than it started.

    python examples/sand_pile.py --out examples_out/sand_pile
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402

HEAP_STRETCH = 4.0  # vertical stretch of the shipped (gentle) pile into a steep heap
SCENE = {
    "up": "z",
    "object": {"size_m": 0.8, "position": [0.0, 0.0, 0.0]},
    "domain": {"size_m": [2.0, 2.0, 1.0]},
    "gravity": [0.0, 0.0, -9.81],
    "ground": {"enabled": True, "height_m": 0.0, "friction": 0.5},
    "materials": {"sand_friction_angle_deg": 30.0},
    # sand flow does not depend on the grains' stiffness: let the solver soften it (fewer substeps)
    "solver": {"max_substeps_per_frame": 150},
}
FULL = _common.Size(frames=25, fps=25.0, grid=40, particles_per_cell=3)
TINY = _common.Size(frames=13, fps=25.0, grid=24, particles_per_cell=1)


def footprint_radius(x):
    """Radius (m) around the vertical axis holding 95 % of the Gaussians, per frame (T,)."""
    import numpy as np

    r = np.hypot(x[:, :, 0] - x[0, :, 0].mean(), x[:, :, 1] - x[0, :, 1].mean())
    return np.quantile(r, 0.95, axis=1)


def main(argv: list[str] | None = None) -> dict:
    args = _common.parser(__doc__, "sand_pile").parse_args(argv)
    out = _common.setup(args)
    cloud = _common.stretch_vertically(_common.annotated_example("sand", args, out), HEAP_STRETCH)
    result = _common.simulate(cloud, SCENE, TINY if args.tiny else FULL, args, out, "sand_pile",
                              elevation_deg=15.0)
    x = result.x_world
    radius = footprint_radius(x)
    height = x[:, :, 2].max(axis=1) - x[:, :, 2].min(axis=1)
    return _common.report("sand_pile", out, result, {
        "radius_before_m": float(radius[0]),
        "radius_after_m": float(radius[-1]),
        "height_before_m": float(height[0]),
        "height_after_m": float(height[-1]),
        "spread_ratio": float(radius[-1] / radius[0]),
        "spread_wider": bool(radius[-1] > 1.1 * radius[0]),
    })


if __name__ == "__main__":
    _common.run_cli(main)
