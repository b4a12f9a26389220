"""Simulation: Particles + Scene → MPMSolver (NVIDIA Warp MLS-MPM) → positions, F, covariances.

`MPMSolver` is imported lazily (it pulls in Warp) so `import pixie_gs.sim` stays light.
"""
from __future__ import annotations

from typing import Any

from .covariance import advect_covariances
from .particles import Particles
from .scene import Scene

__all__ = ["Particles", "Scene", "MPMSolver", "advect_covariances"]


def __getattr__(name: str) -> Any:
    if name == "MPMSolver":
        from .solver import MPMSolver

        return MPMSolver
    raise AttributeError(name)
