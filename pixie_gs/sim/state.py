"""State: the particle arrays that change as the simulation runs, kept outside the solver.

Why: as in NVIDIA Newton, `solver.step(state_in, state_out, dt)` advances a `State` the caller
owns, so one solver (its compiled launches, grid and per-particle material) serves any number of
states — snapshots to restart from, candidate runs of diagnose. A State holds only what a substep
changes: positions x (m), velocities v (m/s), the APIC affine velocity C (1/s), the deformation
gradient F (elastic part for plastic materials), the Kirchhoff stress τ (Pa) the last G2P stored,
snow's plastic volume ratio Jp, and the simulated time (s). Per-particle constants (mass, volume,
μ, λ, material id, fixed flag, yield stress) stay with the solver. Arrays are in the solver's
slot order (see MPMSolver.order).
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import warp as wp

ARRAY_FIELDS = ("x", "v", "C", "F", "stress", "Jp")


@dataclass
class State:
    """Warp arrays of N particles (x, v: vec3; C, F, stress: mat33; Jp: float) and time_s (s)."""

    x: wp.array
    v: wp.array
    C: wp.array
    F: wp.array
    stress: wp.array
    Jp: wp.array
    time_s: float = 0.0

    @classmethod
    def at_rest(cls, x_m: np.ndarray, v_mps: np.ndarray, device: str, time_s: float = 0.0) -> "State":
        """Undeformed particles at positions `x_m` (N,3) m with velocities `v_mps` (N,3) m/s:
        F = I, C = 0, τ = 0, Jp = 1."""
        x = np.ascontiguousarray(x_m, np.float32).reshape(-1, 3)
        n = len(x)
        v = np.ascontiguousarray(np.broadcast_to(np.asarray(v_mps, np.float32), (n, 3)))
        return cls(x=wp.array(x, dtype=wp.vec3, device=device),
                   v=wp.array(v, dtype=wp.vec3, device=device),
                   C=wp.zeros(n, dtype=wp.mat33, device=device),
                   F=wp.array(np.tile(np.eye(3, dtype=np.float32), (n, 1, 1)), dtype=wp.mat33, device=device),
                   stress=wp.zeros(n, dtype=wp.mat33, device=device),
                   Jp=wp.ones(n, dtype=float, device=device),
                   time_s=float(time_s))

    def __len__(self) -> int:
        return self.x.shape[0]

    @property
    def device(self) -> str:
        return str(self.x.device)

    def arrays(self) -> list[wp.array]:
        """The particle arrays, in ARRAY_FIELDS order."""
        return [getattr(self, name) for name in ARRAY_FIELDS]

    def clone(self) -> "State":
        """An independent copy (new device arrays, same values and time)."""
        return State(*(wp.clone(a) for a in self.arrays()), time_s=self.time_s)

    def assign(self, other: "State") -> None:
        """Copy `other`'s values and time into this state's arrays (same N and device)."""
        if len(other) != len(self):
            raise ValueError(f"cannot assign a state of {len(other)} particles to one of {len(self)}")
        for dst, src in zip(self.arrays(), other.arrays()):
            wp.copy(dst, src)
        self.time_s = other.time_s

    def slice(self, start: int, stop: int) -> "State":
        """A view of particles [start, stop) sharing memory with this state (writes go through)."""
        return State(*(a[start:stop] for a in self.arrays()), time_s=self.time_s)

    def numpy(self) -> dict[str, np.ndarray]:
        """Host copies of every array (slot order), keyed by field name."""
        return {name: getattr(self, name).numpy().copy() for name in ARRAY_FIELDS}


assert tuple(f.name for f in fields(State))[: len(ARRAY_FIELDS)] == ARRAY_FIELDS
