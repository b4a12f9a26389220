"""pixie-gs: physics for 3D Gaussian splats (feed-forward materials + Warp MPM).

`SplatCloud`, `read_splat` and `write_splat` are loaded on first use (PEP 562), so `import pixie_gs`
is instant: `python -m pixie_gs` then reaches its own Ctrl-C handling before numpy is imported.
"""
__version__ = "0.1.0"
__all__ = ["SplatCloud", "read_splat", "write_splat", "__version__"]


def __getattr__(name: str):
    if name in ("SplatCloud", "read_splat", "write_splat"):
        from . import splat

        return getattr(splat, name)
    raise AttributeError(f"module 'pixie_gs' has no attribute {name!r}")
