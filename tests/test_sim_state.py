"""State outside the solver: MPMSolver.step(state_in, state_out, dt) on a State (sim/state.py).

References: the solver's own step_frame (the path every physics test checks against analytic
answers), the exact free-fall of the explicit scheme, and snapshot/restart determinism. Runs on
every Warp device present (cpu always, cuda when a GPU is there)."""
from __future__ import annotations

import numpy as np
import pytest

from pixie_gs.materials import JELLY
from pixie_gs.sim import MPMSolver, Particles, Scene
from pixie_gs.sim.state import State
from test_sim_kernels import device  # noqa: F401  (the per-device fixture)

G = 9.81


def block(scene: Scene, **attrs: object) -> Particles:
    attrs = {"E": 1e4, "nu": 0.3, "density": 500.0, "material_id": JELLY, **attrs}
    return Particles.lattice((-0.06, -0.06, 0.05), (0.06, 0.06, 0.15), scene.dx / 2, **attrs)


def toss(**keys: object) -> Scene:
    return Scene.from_dict({"domain": {"size_m": 1.0, "grid": 20}, "ground": {"friction": 0.4},
                            "impulses": [{"time_s": 0.0, "velocity_change": [1.2, 0.3, 0.8]}], **keys})


def exact_tol(device: str) -> float:
    """CPU threads run in order: identical arithmetic gives identical bits; CUDA atomics sum in
    any order (float rounding differences, grown over the run)."""
    return 0.0 if device == "cpu" else 2e-4


def test_step_in_place_repeats_step_frame(device):
    scene = toss()
    p = block(scene)
    ref = MPMSolver(p, scene, device, sort_every=0)
    sim = MPMSolver(p, scene, device, sort_every=0)
    state = sim.new_state()
    for _ in range(4):
        ref.step_frame(1.0 / 30)
        dt = (1.0 / 30) / ref.substeps_last_frame
        for _ in range(ref.substeps_last_frame):
            sim.step(state, state, dt)
        np.testing.assert_allclose(state.x.numpy(), ref.x.numpy(), rtol=0, atol=exact_tol(device))
        np.testing.assert_allclose(state.F.numpy(), ref.F.numpy(), rtol=0, atol=10 * exact_tol(device))
    assert state.time_s == pytest.approx(ref.time_s, abs=1e-12)
    # the solver's own state did not move: step() works only on the states it is given
    np.testing.assert_array_equal(sim.positions(), p.x)
    assert sim.time_s == 0.0


def test_step_out_of_place_leaves_the_input_state_alone(device):
    scene = toss()
    sim = MPMSolver(block(scene), scene, device, sort_every=0)
    s0 = sim.new_state()
    before = s0.numpy()
    s1 = sim.new_state()
    sim.step(s0, s1, 1e-3)
    after = s0.numpy()
    for name in before:
        np.testing.assert_array_equal(after[name], before[name])
    assert s0.time_s == 0.0 and s1.time_s == pytest.approx(1e-3)
    # the impulse at t = 0 lies in [0, 1e-3): applied to the output state only
    assert np.abs(s1.v.numpy()[:, 0] - 1.2).max() < 0.05
    assert np.abs(before["v"]).max() == 0.0


def test_free_fall_of_a_state_follows_the_explicit_scheme(device):
    """No ground, no impulse: v_n = −g·n·dt exactly, z_n = z_0 − g·dt²·n(n+1)/2 (symplectic Euler)."""
    scene = Scene.from_dict({"domain": {"size_m": 1.0, "grid": 20}, "ground": {"enabled": False}})
    p = block(scene)
    p.x[:, 2] += 0.4  # high in the box: 50 substeps of 1 ms fall 12.7 mm
    sim = MPMSolver(p, scene, device, sort_every=0)
    state = sim.new_state()
    dt, n = 1e-3, 50
    for _ in range(n):
        sim.step(state, state, dt)
    z = state.x.numpy()[:, 2]
    expected = p.x[:, 2] - G * dt * dt * n * (n + 1) / 2
    np.testing.assert_allclose(z, expected, atol=1e-5)  # float32 positions: ~1e-7 per step
    np.testing.assert_allclose(state.v.numpy()[:, 2], -G * dt * n, rtol=1e-4)


def test_snapshot_and_restart_is_deterministic(device):
    scene = toss(damping=1.0)
    sim = MPMSolver(block(scene), scene, device, sort_every=0)
    a = sim.new_state()
    for _ in range(20):
        sim.step(a, a, 1e-3)
    snap = a.clone()
    b = State.at_rest(np.zeros((len(a), 3)), np.zeros(3), sim.device)
    for _ in range(30):
        sim.step(a, a, 1e-3)
    sim.step(snap, b, 1e-3)  # out of place once, then in place on b
    for _ in range(29):
        sim.step(b, b, 1e-3)
    assert b.time_s == pytest.approx(a.time_s)
    np.testing.assert_allclose(b.x.numpy(), a.x.numpy(), rtol=0, atol=exact_tol(device))
    moved = np.abs(a.x.numpy() - snap.x.numpy()).max()
    assert moved > 0.01  # it did move between snapshot and end


def test_solver_arrays_are_its_state_and_states_check_their_size(device):
    scene = toss()
    sim = MPMSolver(block(scene), scene, device)
    assert sim.x is sim.state.x and sim.F is sim.state.F and sim.Jp is sim.state.Jp
    sim.step_frame(1.0 / 30)
    assert sim.state.time_s == pytest.approx(sim.time_s)
    small = State.at_rest(np.zeros((3, 3)), np.zeros(3), sim.device)
    with pytest.raises(ValueError, match="particles"):
        sim.step(small, small, 1e-3)
    view = sim.state.slice(0, 5)
    assert len(view) == 5
