"""The solver's device-side helpers against plain references: the frame-statistics reduction
(CFL inputs and divergence guard) against numpy, the cell sort against a numpy argsort, and a
sorted run against an unsorted one. Runs on every Warp device present (cpu always, cuda when a
GPU is there; PIXIE_TEST_DEVICES=cuda picks one)."""
from __future__ import annotations

import os

import numpy as np
import pytest

from pixie_gs.materials import JELLY, METAL, SNOW
from pixie_gs.sim import MPMSolver, Particles, Scene


def _devices() -> list[str]:
    if os.environ.get("PIXIE_TEST_DEVICES"):
        return os.environ["PIXIE_TEST_DEVICES"].split(",")
    import warp as wp

    from pixie_gs.devices import init_warp_quietly

    init_warp_quietly()
    return ["cpu"] + (["cuda"] if wp.is_cuda_available() else [])


@pytest.fixture(params=_devices())
def device(request) -> str:
    return request.param


def mixed_block(scene: Scene, seed: int = 0) -> Particles:
    """Jelly, metal and snow particles in random (file) order, some fixed, random velocities."""
    rng = np.random.default_rng(seed)
    p = Particles.lattice((-0.06, -0.06, 0.02), (0.06, 0.06, 0.1), scene.dx / 2, E=1e5, nu=0.3, density=800.0,
                          material_id=JELLY)
    n = len(p)
    perm = rng.permutation(n)
    mat = rng.choice([JELLY, METAL, SNOW], n).astype(np.int32)
    E = rng.uniform(1e4, 1e6, n)
    fixed = rng.random(n) < 0.1
    v = rng.normal(0.0, 0.3, (n, 3))
    return Particles(x=p.x[perm], v=v, volume=p.volume, E=E, nu=0.3, density=800.0, material_id=mat, fixed=fixed)


def scene_for_tests() -> Scene:
    return Scene.from_dict({"domain": {"size_m": 0.4, "grid": 24}, "ground": {"friction": 0.3}})


def test_device_frame_stats_match_the_numpy_reference(device):
    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device)
    rng = np.random.default_rng(1)
    # a state that exercises every branch: hardened snow, sheared F, and planted failures
    jp = rng.uniform(0.8, 1.1, sim.n)
    sim.set_plastic_volume_ratio(jp)
    F = np.eye(3) + rng.normal(0.0, 0.05, (sim.n, 3, 3))
    bad_nan_x, bad_fast, bad_stretch, bad_inverted, bad_nan_F = 3, 10, 20, 30, 40
    F[bad_stretch] *= 2000.0  # ‖F‖ > 1e3
    F[bad_inverted] = np.diag([1.0, 1.0, -1.0])  # det F < 0
    F[bad_nan_F, 1, 2] = np.nan
    sim.F.assign(F.astype(np.float32))  # slot order: which particle fails does not matter here
    x = sim.x.numpy().copy()
    x[bad_nan_x, 0] = np.inf
    sim.x.assign(x)
    v = sim.v.numpy().copy()
    v[bad_fast] = [0.0, 0.0, 50.0]
    sim.v.assign(v)
    fixed = sim.fixed_flag.numpy()
    v_limit = 5.0
    got, ref = sim.frame_stats(v_limit), sim.reference_frame_stats(v_limit)
    planted = [bad_nan_x, bad_fast, bad_stretch, bad_inverted, bad_nan_F]
    assert got.bad == ref.bad == len(planted)
    assert np.array_equal(got.bad_per_material, ref.bad_per_material)
    assert np.array_equal(ref.bad_per_material, np.bincount(sim.material.numpy()[planted], minlength=7))
    assert got.max_speed_mps == pytest.approx(ref.max_speed_mps, rel=1e-6)
    assert got.max_snow_wave_mps == pytest.approx(ref.max_snow_wave_mps, rel=1e-5)
    # independent of both: the fastest moving, non-failed particle straight from the arrays
    ok = (fixed == 0) & ~np.isin(np.arange(sim.n), planted)
    assert ref.max_speed_mps == pytest.approx(np.linalg.norm(v[ok].astype(np.float64), axis=1).max(), rel=1e-12)
    # without a speed limit the fast particle is no failure and sets the maximum
    assert sim.frame_stats().max_speed_mps == pytest.approx(50.0, rel=1e-6)


def test_device_guard_stays_quiet_on_a_healthy_state_and_counts_per_material(device):
    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device)
    assert sim.frame_stats(5.0).bad == 0  # random speeds ~0.3 m/s, none above 5
    v = sim.velocities()
    fast = np.nonzero((sim.material_id == METAL) & ~sim.fixed)[0][:7]
    v[fast] = [0.0, 9.0, 0.0]
    sim.set_velocities(v)
    stats = sim.frame_stats(5.0)
    assert stats.bad == 7 and stats.bad_per_material[METAL] == 7


def test_a_nan_particle_ends_the_frame_with_the_guard_not_outside_the_grid(device):
    """A particle whose position turned NaN mid-run (a solver fault; stop 53 had one from the rigid solve)
    must not make P2G/G2P index outside the grid arrays (a segfault on a CPU): the stencil base is clamped
    into the grid and the frame's divergence guard reports it as a ComputationError (exit 3)."""
    from pixie_gs.errors import ComputationError

    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device)
    x = sim.x.numpy()
    x[5] = np.nan  # one slot of the device state
    sim.x.assign(x)
    with pytest.raises(ComputationError, match="diverged"):
        sim.step_frame(1.0 / 240)


def test_particle_arrays_are_kept_in_cell_order_and_results_in_file_order(device):
    scene = scene_for_tests()
    p = mixed_block(scene)
    sim = MPMSolver(p, scene, device, sort_every=1)
    order = sim.order.numpy()
    assert np.array_equal(np.sort(order), np.arange(sim.n))  # a permutation
    assert np.array_equal(sim.positions(), p.x)  # accessors answer in file order
    for _ in range(3):  # frames 1 and 2 re-sort at their start
        sim.step_frame(0.01)
    sim._resort()
    xs = sim.x.numpy()
    cell = np.floor((xs.astype(np.float64) - scene.domain_origin()) / scene.dx - 0.5).astype(np.int64)
    dims = np.array(scene.grid_dims)
    assert np.all(np.diff((cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]) >= 0)
    order = sim.order.numpy()
    assert np.array_equal(np.sort(order), np.arange(sim.n))
    # the slot → file map carries values consistently: positions()[order] is the slot array
    assert np.array_equal(sim.positions()[order], xs)
    # and a quantity fixed per particle (its material) is still attached to the right particle
    assert np.array_equal(sim.material.numpy(), p.material_id[order])


def test_cell_order_sorts_like_numpy_argsort(device):
    import warp as wp

    from pixie_gs.sim.sort import cell_order, cell_runs, chunk_runs

    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device, sort_every=0)
    perm, keys = (a.numpy() for a in cell_order(sim.x, sim.grid_info))
    x = sim.x.numpy().astype(np.float64)
    g = (x - scene.domain_origin()) / scene.dx
    cell = np.floor(g - 0.5).astype(np.int64)
    dims = np.array(scene.grid_dims)
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    assert np.array_equal(perm, np.argsort(key, kind="stable"))
    assert np.array_equal(keys, key[perm])
    # runs: a new key, or every MAX_RUN-th particle of a long run
    starts = wp.zeros(sim.n + 1, dtype=wp.int32, device=device)
    counter = wp.zeros(1, dtype=wp.int32, device=device)
    cell_runs(wp.array(keys, dtype=wp.int32, device=device), starts, counter, max_run=4)
    count = int(counter.numpy()[0])
    i = np.arange(sim.n)
    heads = i[(i == 0) | (np.r_[0, np.diff(keys)] != 0) | (i % 4 == 0)]
    assert count == len(heads)
    assert np.array_equal(starts.numpy()[:count + 1], np.append(heads, sim.n))
    # and the runs of the unsorted case: fixed chunks
    chunk_runs(sim.n, 7, starts, counter)
    assert int(counter.numpy()[0]) == -(-sim.n // 7)
    assert np.array_equal(starts.numpy()[:-(-sim.n // 7) + 1], np.append(np.arange(0, sim.n, 7), sim.n))


def test_sorted_and_unsorted_runs_agree(device):
    scene = scene_for_tests()
    p = mixed_block(scene)
    runs = []
    for sort_every in (0, 1):
        sim = MPMSolver(p, scene, device, sort_every=sort_every)
        for _ in range(4):
            sim.step_frame(1 / 60)
        runs.append((sim.positions(), sim.velocities(), sim.deformation_gradients(), sim.substeps_last_frame))
    (x0, v0, F0, n0), (x1, v1, F1, n1) = runs
    assert n0 == n1
    assert not np.array_equal(x0, p.x)  # it moved
    assert np.abs(x0 - x1).max() < 1e-5  # m; float rounding of the atomic sums only
    assert np.abs(v0 - v1).max() < 1e-4  # m/s
    # F ≈ I + O(1e-3) after ~400 substeps of float32 (ulp 6e-8 near 1): elastic and metal agree to
    # rounding; snow's return mapping and hardening amplify it (still ≪ its 2.5e-2 clamp)
    # (on a GPU the atomic sums' order changes from run to run too: a looser bound)
    snow = p.material_id == SNOW
    assert np.abs(F0 - F1)[~snow].max() < (2e-5 if device == "cpu" else 1e-4)
    assert np.abs(F0 - F1)[snow].max() < 5e-4


def scatter(sim: MPMSolver, kernel: str, runs: np.ndarray | None = None,
            index: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """(grid mass, momentum, fixed weight) after one P2G of `kernel`: "atomic", or "chunked" with
    one thread per run (`runs`: run starts followed by N) over particles index[i] (default: i)."""
    import warp as wp

    from pixie_gs.sim import kernels

    d = sim.device
    out = [wp.zeros(sim.dims, dtype=t, device=d) for t in (float, wp.vec3, float)]
    inputs = [sim.x, sim.v, sim.C, sim.stress, sim.volume, sim.mass, sim.fixed_flag, sim.grid_info, 1e-3]
    if kernel == "atomic":
        wp.launch(kernels.p2g, dim=sim.n, device=d, inputs=inputs + out)
    else:
        starts = wp.array(np.asarray(runs, np.int32), dtype=wp.int32, device=d)
        count = wp.array([len(runs) - 1], dtype=wp.int32, device=d)
        index = np.arange(sim.n) if index is None else index
        order = wp.array(np.asarray(index, np.int32), dtype=wp.int32, device=d)
        wp.launch(kernels.p2g_chunked, dim=sim.n, device=d, inputs=inputs + [starts, count, order] + out)
    return tuple(a.numpy() for a in out)


@pytest.mark.parametrize("order", ["sorted", "file"])
def test_chunked_p2g_matches_the_plain_atomic_kernel(device, order):
    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device, sort_every=1 if order == "sorted" else 0)
    rng = np.random.default_rng(2)
    sim.C.assign(rng.normal(0.0, 1.0, (sim.n, 3, 3)).astype(np.float32))
    sim.stress.assign(rng.normal(0.0, 100.0, (sim.n, 3, 3)).astype(np.float32))
    reference = scatter(sim, "atomic")
    # the solver's own cell runs; fixed-size chunks that end inside a cell run, at its end, or
    # hold many runs; one thread for everything
    own = sim.run_start.numpy()[:sim.n_runs + 1]
    cases = [(own, None)] + [(np.append(np.arange(0, sim.n, c), sim.n), None) for c in (1, 8, 13, sim.n)]
    cases.append((np.append(np.arange(0, sim.n, 8), sim.n), rng.permutation(sim.n)))  # through an index
    for runs, index in cases:
        fast = scatter(sim, "chunked", runs, index)
        for a, b in zip(reference, fast):
            assert np.abs(a - b).max() <= 1e-5 * np.abs(a).max()  # summation order only
    # and the independent sums: total mass and momentum are the particles' own
    mass = sim.mass.numpy().astype(np.float64)
    assert fast[0].sum() == pytest.approx(mass.sum(), rel=1e-5)
    momentum = (mass[:, None] * sim.v.numpy()).sum(0)  # the affine part sums to 0 (B-spline moments)
    assert np.allclose(fast[1].reshape(-1, 3).sum(0), momentum, rtol=1e-4, atol=1e-9)


def test_solver_with_fast_p2g_agrees_with_the_atomic_one(device):
    from pixie_gs.sim import solver as solver_module

    scene = scene_for_tests()
    p = mixed_block(scene)
    runs = []
    for kind in ("atomic", "chunked"):
        sim = MPMSolver(p, scene, device, p2g=kind, sort_every=1)
        for _ in range(2):
            sim.step_frame(1 / 60)
        runs.append(sim.positions())
    assert sim.substeps_last_frame > 2 * solver_module.SORT_SUBSTEPS  # the in-frame index re-sorts ran
    assert np.abs(runs[0] - runs[1]).max() < 1e-5


def moving_block(scene: Scene) -> Particles:
    """mixed_block with nothing held (its held particles pin nearly every node) sliding at
    ~0.6 cells per frame in x: particles leave their cells within a frame."""
    import dataclasses

    p = mixed_block(scene)
    return dataclasses.replace(p, v=p.v + np.array([0.6, 0.0, 0.0]), fixed=np.zeros(len(p.x), bool))


class MarkRecorder:
    """solver.kernel_timer that only records the names marked (which kernels/sorts ran)."""

    def __init__(self) -> None:
        self.names: list[str] = []

    def mark(self, name: str) -> None:
        self.names.append(name)


def test_resort_inside_the_frame_agrees_and_keeps_the_order_map(device):
    from pixie_gs.sim import solver as solver_module

    scene = scene_for_tests()
    p = moving_block(scene)
    reference = MPMSolver(p, scene, device, p2g="atomic", sort_every=1)
    sim = MPMSolver(p, scene, device, p2g="chunked", sort_every=1, sort_substeps=5, resort_inside=True)
    recorder = MarkRecorder()
    for frame in range(3):
        order_before = sim.order.numpy().copy()
        sim.kernel_timer = recorder if frame == 1 else None
        for s in (reference, sim):
            s.step_frame(1 / 60)
        assert sim.substeps_last_frame > solver_module.RESORT_SUBSTEP
        if frame == 1:  # frames after the first re-sort inside, at the first index sort from substep 16 on
            marks = [m for m in recorder.names if m in ("sort", "resort")]
            assert marks == ["sort"] * 3 + ["resort"] + ["sort"] * (len(marks) - 4)
            assert not np.array_equal(sim.order.numpy(), order_before)  # particles changed cells: new order
        assert np.abs(reference.positions() - sim.positions()).max() < 1e-5  # m, in the caller's order
        assert np.abs(reference.velocities() - sim.velocities()).max() < 1e-4  # m/s
    # the arrays were left in cell order by the last re-sort, as far as particles moved since
    assert np.array_equal(sim.material.numpy(), p.material_id[sim.order.numpy()])


def test_register_capped_g2p_matches_g2p(device):
    import warp as wp

    from pixie_gs.sim import kernels
    from pixie_gs.sim.state import ARRAY_FIELDS

    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device, sort_every=0)  # jelly, metal, snow; some held
    rng = np.random.default_rng(4)
    sim.F.assign((np.eye(3) + rng.normal(0.0, 0.1, (sim.n, 3, 3))).astype(np.float32))
    grid_v = wp.array(rng.normal(0.0, 0.5, (*sim.dims, 3)).astype(np.float32), dtype=wp.vec3, device=device)
    capped = kernels.register_capped(kernels.g2p, 64)
    assert kernels.register_capped(kernels.g2p, None) is kernels.g2p and kernels.register_capped(kernels.g2p, 64) is capped
    outs = []
    for kernel in (kernels.g2p, capped):
        st = sim.state.clone()
        wp.launch(kernel, dim=sim.n, device=device,
                  inputs=[st.x, st.v, st.C, st.F, sim.mu, sim.lam, sim.yield_stress, sim.material, st.Jp,
                          sim.fixed_flag, sim.grid_info, sim.material_params, 1e-3, grid_v, st.stress])
        outs.append(st.numpy())
    before = sim.state.numpy()
    assert np.abs(outs[0]["x"] - before["x"]).max() > 1e-5  # it moved the particles
    assert np.abs(outs[0]["stress"]).max() > 1.0  # and stressed them (Pa)
    for name in ARRAY_FIELDS:  # the same code: only register allocation differs on a GPU
        a, b = outs[0][name], outs[1][name]
        assert np.abs(a - b).max() <= 1e-6 * max(1.0, np.abs(a).max()), name
    assert MPMSolver(mixed_block(scene), scene, device, sort_every=0, g2p_max_registers=64)._g2p.kernel is capped

