"""pixie-gs: physics for 3D Gaussian splats (feed-forward materials + Warp MPM)."""
from .splat import SplatCloud, read_splat, write_splat

__version__ = "0.1.0"
__all__ = ["SplatCloud", "read_splat", "write_splat", "__version__"]
