"""The column P2G kernels (sim/p2g_column.py: nine or three threads per run of one column of
cells, sliding node windows along z, into a packed vec4 grid) against their plain reference
kernels.p2g, the packed grid update against kernels.grid_update, the column runs against numpy,
and solvers using them against the atomic solver. Runs on every Warp device present (cpu
always, cuda when a GPU is there; PIXIE_TEST_DEVICES=cuda picks one): on sm_90 the node sums
go out as 16-byte vector atomics, so the CUDA run is what checks that path."""
from __future__ import annotations

import numpy as np
import pytest

from pixie_gs.sim import MPMSolver, Particles, Scene, kernels, p2g_column
from pixie_gs.sim import solver as solver_module
from test_sim_kernels import MarkRecorder, device, mixed_block, moving_block, scene_for_tests  # noqa: F401
from test_sim_physics import join
from test_sim_rigid import AL, free_scene

KERNELS = ("column", "slab")
STATE_FIELDS = ("x", "v", "C", "stress", "F", "Jp")


def sorted_keys(sim: MPMSolver, scene: Scene) -> np.ndarray:
    """Cell keys (z fastest) of the solver's particles in slot order, in numpy."""
    cell = np.floor((sim.x.numpy().astype(np.float64) - scene.domain_origin()) / scene.dx - 0.5).astype(np.int64)
    dims = np.array(scene.grid_dims)
    return (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]


def test_column_runs_start_at_each_new_column_and_every_max_run(device):
    import warp as wp

    from pixie_gs.sim.sort import cell_runs

    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device, sort_every=1)
    keys = sorted_keys(sim, scene)
    assert np.all(np.diff(keys) >= 0)  # the solver sorted its arrays
    nz = scene.grid_dims[2]
    starts = wp.zeros(sim.n + 1, dtype=wp.int32, device=device)
    counter = wp.zeros(1, dtype=wp.int32, device=device)
    run_keys = wp.zeros(sim.n, dtype=wp.int32, device=device)
    i = np.arange(sim.n)
    column = keys // nz
    for max_run in (5, 64):
        cell_runs(wp.array(keys.astype(np.int32), dtype=wp.int32, device=device), starts, counter, max_run=max_run,
                  column=nz, run_keys=run_keys)
        heads = i[(i == 0) | (np.r_[0, np.diff(column)] != 0) | (i % max_run == 0)]
        count = int(counter.numpy()[0])
        assert count == len(heads) < sim.n
        assert np.array_equal(starts.numpy()[:count + 1], np.append(heads, sim.n))
        assert np.array_equal(run_keys.numpy()[:count], keys[heads])
        for a, b in zip(heads, np.append(heads[1:], sim.n)):  # never two columns in a run
            assert len(np.unique(column[a:b])) == 1
    assert count < len(np.unique(keys)) / 2  # runs of 64: several cells of one column each


def scatter_column(sim: MPMSolver, kind: str, max_run: int, index: np.ndarray | None = None,
                   vector: int = 1, keys_from: np.ndarray | None = None, carry: bool = False,
                   state=None) -> tuple[np.ndarray, ...]:
    """(grid mass, momentum, fixed weight) after one P2G of the column kernel `kind` (`carry`: its
    twin that reads affine matrices from `stress`) over runs of the cell keys `keys_from` (default:
    the particles' own, in slot order) and particles index[i]; `state`: the particle arrays to
    read (default: the solver's)."""
    import warp as wp

    from pixie_gs.sim import p2g_column
    from pixie_gs.sim.sort import cell_runs

    d = sim.device
    plain, twin, per_run = solver_module.COLUMN_KINDS[kind]
    kernel = twin if carry else plain
    st = sim.state if state is None else state
    keys = sorted_keys(sim, sim.scene) if keys_from is None else keys_from
    starts = wp.zeros(sim.n + 1, dtype=wp.int32, device=d)
    counter = wp.zeros(1, dtype=wp.int32, device=d)
    run_keys = wp.zeros(sim.n, dtype=wp.int32, device=d)
    cell_runs(wp.array(keys.astype(np.int32), dtype=wp.int32, device=d), starts, counter, max_run=max_run,
              column=sim.dims[2], run_keys=run_keys)
    order = wp.array(np.arange(sim.n, dtype=np.int32) if index is None else index.astype(np.int32), dtype=wp.int32,
                     device=d)
    grid_mv = wp.zeros(sim.dims, dtype=wp.vec4, device=d)
    grid_fixed = wp.zeros(sim.dims, dtype=float, device=d)
    wp.launch(kernel, dim=p2g_column.column_threads(sim.n, max_run, sim.dims, per_run), device=d,
              inputs=[st.x, st.v, st.C, st.stress, sim.volume, sim.mass, sim.fixed_flag, sim.grid_info, 1e-3,
                      starts, counter, run_keys, order, vector, grid_mv, grid_fixed])
    mv = grid_mv.numpy()
    return mv[..., 3], mv[..., :3], grid_fixed.numpy()


def scatter_atomic(sim: MPMSolver) -> tuple[np.ndarray, ...]:
    import warp as wp

    from pixie_gs.sim import kernels

    d = sim.device
    out = [wp.zeros(sim.dims, dtype=t, device=d) for t in (float, wp.vec3, float)]
    wp.launch(kernels.p2g, dim=sim.n, device=d,
              inputs=[sim.x, sim.v, sim.C, sim.stress, sim.volume, sim.mass, sim.fixed_flag, sim.grid_info, 1e-3]
              + out)
    return tuple(a.numpy() for a in out)


def assert_same_grid(reference: tuple[np.ndarray, ...], fast: tuple[np.ndarray, ...]) -> None:
    for a, b in zip(reference, fast):
        assert np.abs(a - b).max() <= 1e-5 * np.abs(a).max()  # summation order only


def sparse(p: Particles, keep: float, seed: int = 7) -> Particles:
    """A random `keep` fraction of the particles: columns of cells with empty cells between
    occupied ones (the window jumps more than its 3 nodes)."""
    mask = np.random.default_rng(seed).random(len(p.x)) < keep
    fields = ("x", "v", "volume", "E", "nu", "density", "material_id", "yield_stress", "fixed", "part_id")
    return Particles(**{f: getattr(p, f)[mask] for f in fields})


@pytest.mark.parametrize("kind", KERNELS)
@pytest.mark.parametrize("keep", [1.0, 0.08])
def test_column_p2g_matches_the_plain_atomic_kernel(device, kind, keep):
    scene = scene_for_tests()
    p = mixed_block(scene)  # jelly, metal, snow; 10 % held
    sim = MPMSolver(p if keep == 1.0 else sparse(p, keep), scene, device, sort_every=1)
    if keep < 1.0:  # consecutive particles of a column three or more cells apart
        keys = sorted_keys(sim, scene)
        same_column = np.diff(keys // scene.grid_dims[2]) == 0
        assert (np.diff(keys)[same_column] >= 3).sum() >= 5
    rng = np.random.default_rng(2)
    sim.C.assign(rng.normal(0.0, 1.0, (sim.n, 3, 3)).astype(np.float32))
    sim.stress.assign(rng.normal(0.0, 100.0, (sim.n, 3, 3)).astype(np.float32))
    reference = scatter_atomic(sim)
    assert reference[2].max() > 0.0  # held particles mark nodes
    keys = sorted_keys(sim, scene)
    # runs of whole columns, runs that end inside a cell, one particle per run; vector atomics
    # on and off (the same code off sm_90); every particle through a shuffled index, so the runs
    # (from the sorted keys) hold particles of other columns and out of z order: the direct path
    cases = [(32, None, 1), (3, None, 1), (1, None, 0), (32, None, 0), (8, rng.permutation(sim.n), 1)]
    for max_run, index, vector in cases:
        fast = scatter_column(sim, kind, max_run, index, vector, keys_from=keys)
        assert_same_grid(reference, fast)
    # the independent sums: total mass and momentum are the particles' own
    mass = sim.mass.numpy().astype(np.float64)
    assert fast[0].sum() == pytest.approx(mass.sum(), rel=1e-5)
    momentum = (mass[:, None] * sim.v.numpy()).sum(0)  # the affine part sums to 0 (B-spline moments)
    assert np.allclose(fast[1].reshape(-1, 3).sum(0), momentum, rtol=1e-4, atol=1e-9)


@pytest.mark.parametrize("kind", KERNELS)
def test_column_p2g_is_right_after_particles_drift_out_of_their_sorted_cells(device, kind):
    """Runs from the sort, positions moved since by up to ±0.8 cells per axis (what happens
    between in-frame re-sorts): particles step up and down the window and leave the column."""
    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device, sort_every=1)
    rng = np.random.default_rng(3)
    sim.stress.assign(rng.normal(0.0, 100.0, (sim.n, 3, 3)).astype(np.float32))
    keys = sorted_keys(sim, scene)
    x = sim.x.numpy()
    sim.x.assign((x + rng.uniform(-0.8, 0.8, x.shape) * scene.dx).astype(np.float32))
    moved = sorted_keys(sim, scene) != keys
    assert 0.5 < moved.mean() < 1.0  # most particles changed cell, some did not
    reference = scatter_atomic(sim)
    for max_run in (32, 4):
        assert_same_grid(reference, scatter_column(sim, kind, max_run, keys_from=keys))


def test_packed_grid_update_matches_grid_update(device):
    import warp as wp

    from pixie_gs.sim import kernels, p2g_column

    scene = Scene.from_dict({"domain": {"size_m": 0.4, "grid": 16}, "ground": {"friction": 0.4, "height_m": 0.02},
                             "damping": 2.0, "air_drag": 0.5,
                             "wind": [{"acceleration": [3.0, 0.0, 0.0], "region": {"min": [-1, -1, 0.1],
                                                                                    "max": [1, 1, 1]}}]})
    sim = MPMSolver(mixed_block(scene), scene, device, sort_every=0)
    rng = np.random.default_rng(5)
    dims = sim.dims
    mass = np.where(rng.random(dims) < 0.7, rng.uniform(0.1, 1.0, dims), 0.0).astype(np.float32)
    momentum = rng.normal(0.0, 0.5, (*dims, 3)).astype(np.float32) * (mass[..., None] > 0)
    held = (rng.random(dims) < 0.1).astype(np.float32)
    outs = []
    stale = rng.normal(0.0, 1.0, (*dims, 3)).astype(np.float32)  # velocities left from an earlier substep
    for packed in (False, True):
        fixed = wp.array(held, dtype=float, device=device)
        velocity = wp.array(stale, dtype=wp.vec3, device=device)
        if packed:
            grid_in = [wp.array(np.concatenate([momentum, mass[..., None]], -1), dtype=wp.vec4, device=device)]
        else:
            grid_in = [wp.array(mass, dtype=float, device=device), wp.array(momentum, dtype=wp.vec3, device=device)]
        sc = scene
        wp.launch(p2g_column.grid_update_packed if packed else kernels.grid_update, dim=dims, device=device,
                  inputs=grid_in + [fixed, velocity, sim.grid_info, wp.vec3i(0, 0, 0), 1e-3, 0.5,
                                    wp.vec3(*sc.gravity), sim.wind_acc, sim.wind_lo, sim.wind_hi, sim.wind_timing,
                                    len(sc.wind), sc.damping, sc.air_drag, 1, sc.ground.height_m, sc.ground.friction,
                                    0, 3])
        outs.append(velocity.numpy())
        assert all(not a.numpy().any() for a in grid_in + [fixed])  # cleared for the next P2G
    empty = (mass == 0) & (held == 0)
    assert np.array_equal(outs[0][~empty], outs[1][~empty])
    assert np.abs(outs[0]).max() > 0.1 and not outs[0][held > 0].any()
    # empty nodes: the packed update leaves them alone (no particle reads them with weight > 0)
    assert not outs[0][empty].any() and np.array_equal(outs[1][empty], stale[empty])


@pytest.mark.parametrize("kind", KERNELS)
def test_solver_with_column_p2g_agrees_with_the_atomic_one(device, kind):
    scene = scene_for_tests()
    p = moving_block(scene)  # slides ~0.6 cells per frame: particles leave their cells inside a frame
    reference = MPMSolver(p, scene, device, p2g="atomic", sort_every=1)
    sim = MPMSolver(p, scene, device, p2g=kind, sort_every=1, sort_substeps=5, column_run=8)
    assert sim.grid_momentum is None and sim.grid_mv is not None  # the packed grid only
    recorder = MarkRecorder()
    sim.kernel_timer = recorder
    for _ in range(3):
        for s in (reference, sim):
            s.step_frame(1 / 60)
        assert np.abs(reference.positions() - sim.positions()).max() < 1e-5  # m, in the caller's order
        assert np.abs(reference.velocities() - sim.velocities()).max() < 1e-4  # m/s
    assert recorder.names.count("sort") >= 3 * (sim.substeps_last_frame // 5 - 1)  # the in-frame re-sorts ran
    assert np.array_equal(sim.material.numpy(), p.material_id[sim.order.numpy()])


def test_column_p2g_with_a_rigid_body_agrees_with_the_atomic_one(device):
    """Rigid coupling reads the node masses: the packed grid hands them over (p2g_column.packed_mass).
    Rigid bodies overwrite C and τ after G2P, so a solver asked to carry the affine matrices (and
    the default, which does so on a GPU) computes them in P2G instead once a body exists."""
    scene = free_scene(gravity=[0, 0, 0])
    rigid = Particles.lattice((-0.2, -0.05, -0.05), (-0.1, 0.05, 0.05), scene.dx / 2, v=[2.0, 0, 0], **AL)
    soft = Particles.lattice((-0.06, -0.05, -0.05), (0.04, 0.05, 0.05), scene.dx / 2, E=2e4, nu=0.3,
                             density=1000.0, material_id=0)
    both = join(rigid, soft)
    configs = ({"p2g": "atomic"}, {"p2g": "column"}, {"p2g": "column", "carry_affine": True}, {})  # {}: auto
    runs = [MPMSolver(both, scene, device, sort_every=1, **c) for c in configs]
    assert runs[2].carrying and runs[3].carrying == (device != "cpu")  # no body yet
    for _ in range(4):
        for s in runs:
            s.step_frame(1 / 60)
    assert all(s.rigid is not None and not s.carrying for s in runs)
    assert runs[2].carry_affine and runs[3].p2g_kind == ("atomic" if device == "cpu" else "column")
    for s in runs[1:]:
        assert np.abs(runs[0].positions() - s.positions()).max() < 1e-5
    if device == "cpu":  # carrying off: the column solver asked to carry runs the plain one's floats
        assert np.array_equal(runs[1].positions(), runs[2].positions())
    assert np.abs(runs[0].velocities()[len(rigid):, 0]).max() > 0.05  # the soft block was hit


def test_p2g_choice_per_device_and_options():
    """solver.p2g_choice, the rule MPMSolver applies (pure: the GPU rows run without a GPU)."""
    from pixie_gs.sim.solver import p2g_choice

    gpu = ("column", True, 128)  # GPU_P2G, GPU_CARRY_AFFINE, GPU_P2G_BLOCK_DIM
    assert (solver_module.GPU_P2G, solver_module.GPU_CARRY_AFFINE, solver_module.GPU_P2G_BLOCK_DIM) == gpu
    rows = [  # (p2g, device, sort_every, carry_affine, block) -> (kind, carry, block)
        (("auto", "cuda:0", 1, None, None), gpu),
        (("auto", "cuda:0", 0, None, None), ("atomic", False, None)),  # a GPU without sorting (small runs)
        (("auto", "cpu", 1, None, None), ("atomic", False, None)),  # the CPU: as before
        (("auto", "cpu", 0, None, None), ("atomic", False, None)),
        (("auto", "cuda:0", 1, False, None), ("column", False, 128)),  # options given are kept
        (("auto", "cuda:0", 1, None, 256), ("column", True, 256)),
        (("column", "cuda:0", 1, None, None), ("column", False, None)),  # a kind by name: as before
        (("column", "cuda:0", 1, True, 128), gpu),
        (("chunked", "cuda:0", 1, None, None), ("chunked", False, None)),
        (("slab", "cpu", 1, True, None), ("slab", True, None)),
        (("atomic", "cuda:0", 1, None, None), ("atomic", False, None)),
    ]
    for args, expected in rows:
        assert p2g_choice(*args) == expected, args
    for args, message in ((("auto", "cpu", 1, True, None), "carry_affine"), (("chunked", "cuda:0", 1, True, None),
                          "carry_affine"), (("column", "cuda:0", 0, None, None), "cell order"),
                          (("blocks", "cpu", 1, None, None), "p2g must be")):
        with pytest.raises(ValueError, match=message):
            p2g_choice(*args)


def test_auto_p2g_is_the_column_kernel_carrying_on_a_gpu_and_atomic_on_the_cpu(device):
    """The default P2G per device (solver.GPU_P2G and friends: the fastest measured on the H100)."""
    scene = scene_for_tests()
    p = mixed_block(scene)  # 1,960 particles: a GPU does not sort so few (SORT_MIN_PARTICLES)
    unsorted = MPMSolver(p, scene, device)
    assert (unsorted.sort_every, unsorted.p2g_kind) == ((1, "atomic") if device == "cpu" else (0, "atomic"))
    sim = MPMSolver(p, scene, device, sort_every=1)
    if device == "cpu":  # unchanged: the atomic P2G, nothing carried, no block size set
        for s in (unsorted, sim):
            assert (s.p2g_kind, s.carry_affine, s.p2g_block_dim, s._p2g_carry) == ("atomic", False, None, None)
        with pytest.raises(ValueError, match="carry_affine"):
            MPMSolver(p, scene, device, sort_every=1, carry_affine=True)
    else:
        assert not unsorted.carry_affine and unsorted._p2g.kernel is kernels.p2g
        assert (sim.p2g_kind, sim.carry_affine, sim.p2g_block_dim) == ("column", True, 128)
        assert sim._p2g.kernel is p2g_column.p2g_column and sim._p2g_carry.kernel is p2g_column.p2g_column_carry
        assert sim._p2g.block_dim == sim._p2g_carry.block_dim == 128 and sim.carrying
        own = MPMSolver(p, scene, device, sort_every=1, carry_affine=False, p2g_block_dim=256)  # given: kept
        assert (own.p2g_kind, own.carry_affine, own._p2g_carry, own._p2g.block_dim) == ("column", False, None, 256)
    for kind in ("column", "chunked"):  # a kind asked for by name: its options as before (no carry, 256)
        named = MPMSolver(p, scene, device, p2g=kind, sort_every=1)
        assert (named.p2g_kind, named.carry_affine, named.p2g_block_dim) == (kind, False, None)


def test_column_p2g_needs_sorting_and_says_so():
    scene = scene_for_tests()
    with pytest.raises(ValueError, match="cell order"):
        MPMSolver(mixed_block(scene), scene, "cpu", p2g="column", sort_every=0)
    with pytest.raises(ValueError, match="column_run"):
        MPMSolver(mixed_block(scene), scene, "cpu", p2g="column", column_run=0)


def test_vector_atomics_are_used_exactly_where_the_compiled_architecture_has_them(device):
    import warp as wp

    from pixie_gs.sim.p2g_column import vector_atomics_active

    if device == "cpu":
        assert not vector_atomics_active(device)
    else:
        assert vector_atomics_active(device) == (wp.get_device(device).get_cuda_compile_arch() >= 90)


def test_g2p_carry_stores_the_next_p2g_affine_matrix(device):
    import warp as wp

    from pixie_gs.sim import kernels, p2g_column

    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device, sort_every=0)  # jelly, metal, snow; some held
    rng = np.random.default_rng(4)
    sim.F.assign((np.eye(3) + rng.normal(0.0, 0.1, (sim.n, 3, 3))).astype(np.float32))
    sim.stress.assign(rng.normal(0.0, 50.0, (sim.n, 3, 3)).astype(np.float32))
    grid_v = wp.array(rng.normal(0.0, 0.5, (*sim.dims, 3)).astype(np.float32), dtype=wp.vec3, device=device)
    dt = 1e-3
    outs = []
    for carry in (False, True):
        st = sim.state.clone()
        st.C.assign(np.full((sim.n, 3, 3), 7.0, np.float32))  # to see which C the kernel writes
        inputs = [st.x, st.v, st.C, st.F, sim.mu, sim.lam, sim.yield_stress, sim.material, st.Jp, sim.fixed_flag,
                  sim.grid_info, sim.material_params, dt, grid_v, st.stress]
        wp.launch(p2g_column.g2p_carry if carry else kernels.g2p, dim=sim.n, device=device,
                  inputs=inputs + ([sim.volume, sim.mass] if carry else []))
        outs.append(st.numpy())
    plain, carried = outs
    held = sim.fixed_flag.numpy() != 0
    for name in ("x", "v", "F", "Jp"):
        assert np.array_equal(plain[name], carried[name]), name
    assert np.abs(plain["stress"][~held]).max() > 1.0  # stressed (Pa)
    # moving particles: the affine matrix of kernels.mls_affine, C left alone; held: as g2p
    m = sim.mass.numpy()[:, None, None]
    k = dt * sim.volume.numpy()[:, None, None] * 4.0 / scene.dx ** 2
    affine = -k * plain["stress"] + m * plain["C"]
    # no noise here (one G2P from the same grid, no atomics): float32 rounding of the affine only
    assert np.abs(affine[~held]).max() > 1e-3
    assert np.allclose(carried["stress"][~held], affine[~held], rtol=1e-6, atol=1e-6 * np.abs(affine).max())
    assert np.all(carried["C"][~held] == 7.0)
    assert np.array_equal(carried["stress"][held], plain["stress"][held]) and not carried["C"][held].any()


@pytest.mark.parametrize("kind", KERNELS)
def test_carry_p2g_twin_reading_affine_matrices_equals_the_plain_p2g(device, kind):
    """The other half of carry_affine, without noise: one P2G of the carry twin, given in `stress`
    the affine matrices mls_affine(dt, V, τ, m, C) of the moving particles (and their C
    overwritten: it must not be read), scatters what the plain kernel does from τ and C. Held
    particles keep a nonzero τ and C here (in a run they are 0), so a twin that took their
    `stress` for an affine matrix would fail."""
    scene = scene_for_tests()
    sim = MPMSolver(mixed_block(scene), scene, device, sort_every=1)  # jelly, metal, snow; 10 % held
    rng = np.random.default_rng(6)
    C = rng.normal(0.0, 1.0, (sim.n, 3, 3))
    tau = rng.normal(0.0, 100.0, (sim.n, 3, 3))
    sim.C.assign(C.astype(np.float32))
    sim.stress.assign(tau.astype(np.float32))
    dt = 1e-3  # scatter_column's
    k = dt * sim.volume.numpy().astype(np.float64)[:, None, None] * 4.0 / scene.dx ** 2
    m = sim.mass.numpy().astype(np.float64)[:, None, None]
    affine = -k * sim.stress.numpy() + m * sim.C.numpy()
    held = sim.fixed_flag.numpy() != 0
    assert 0 < held.sum() < sim.n and np.abs(m * C).max() > 0.1 * np.abs(k * tau).max()  # both terms count
    st = sim.state.clone()
    st.stress.assign(np.where(held[:, None, None], tau, affine).astype(np.float32))
    st.C.assign(np.where(held[:, None, None], C, 7.0).astype(np.float32))
    keys = sorted_keys(sim, scene)
    for max_run in (32, 3):
        reference = scatter_column(sim, kind, max_run, keys_from=keys)
        carried = scatter_column(sim, kind, max_run, keys_from=keys, carry=True, state=st)
        assert_same_grid(reference, carried)
        if device == "cpu":  # the same summation order: only the affine's rounding differs
            for a, b in zip(reference, carried):
                assert np.abs(a - b).max() <= 1e-6 * np.abs(a).max()


def sheared_block(scene: Scene) -> Particles:
    """moving_block (jelly, metal, snow sliding ~0.6 cells per frame) held along its bottom
    layer: it shears over the held layer, so C (~7 /s) and τ (~1e4 Pa) are well above the float
    noise; held particles are in the P2G (their τ and C = 0 are its inputs)."""
    import dataclasses

    p = moving_block(scene)
    return dataclasses.replace(p, fixed=p.x[:, 2] < p.x[:, 2].min() + 0.6 * scene.dx)


CARRY_NOISE_FACTOR = 4  # carried vs plain may differ by this multiple of the plain runs' own spread


@pytest.mark.parametrize("kind", KERNELS)
def test_carried_affine_matrices_give_the_same_frames_and_state(device, kind):
    """carry_affine only moves where mls_affine is computed: every frame and the state it ends
    with (C and τ included: the last G2P of a frame stores them as usual) match the plain run.

    On the CPU the sums run in the same order: the same floats, bit for bit. On a GPU the atomics'
    order changes from run to run, and a rounding difference grows over ~200 substeps (snow and
    metal yield, contact; C ~ Σ w·v·(x_i − x_p)·4/dx² turns a grid-velocity difference δv into
    ~4·δv/dx ≈ 240·δv /s at this dx). So the floor is measured here, on the device: the spread
    between two plain runs, and between a plain run and one whose velocities start 1 ulp up (that
    one also on the CPU: there ~3e-4 of max |C| and ~3e-3 of max |τ|); the carried run must stay within
    CARRY_NOISE_FACTOR × that floor of the plain run. The floor must be small next to the fields
    themselves, or this test could not see a real difference. Noise-free checks of the same path:
    test_g2p_carry_stores_the_next_p2g_affine_matrix, test_carry_p2g_twin_reading_affine_matrices_
    equals_the_plain_p2g."""
    scene = scene_for_tests()
    p = sheared_block(scene)

    def run(carry: bool, nudge: bool = False, inside: bool = False) -> tuple[MPMSolver, dict[str, np.ndarray]]:
        sim = MPMSolver(p, scene, device, p2g=kind, sort_every=1, sort_substeps=5, carry_affine=carry,
                        resort_inside=inside)
        sim.kernel_timer = MarkRecorder()
        if nudge:
            sim.v.assign(np.nextafter(sim.v.numpy(), np.float32(np.inf)))
        for _ in range(2):
            sim.step_frame(1 / 60)
        assert ("resort" in sim.kernel_timer.names) == inside
        return sim, {name: sim._to_caller(getattr(sim, name).numpy()) for name in STATE_FIELDS}

    plain_sim, plain = run(False)
    carried_sim, carried = run(True)
    assert carried_sim._g2p_carry is not None and carried_sim._p2g_carry is not None
    assert plain_sim._g2p_carry is None and carried_sim.substeps_last_frame > 5
    again, nudged = run(False)[1], run(False, nudge=True)[1]
    # the second frame's array re-sort inside the frame (resort_inside): it permutes `stress`
    # while it holds affine matrices
    plain_inside, carried_inside = run(False, inside=True)[1], run(True, inside=True)[1]
    for name in STATE_FIELDS:
        scale = np.abs(plain[name]).max()
        floor = max(np.abs(plain[name] - again[name]).max(), np.abs(plain[name] - nudged[name]).max())
        diff = np.abs(plain[name] - carried[name]).max()
        report = f"{name}: max |plain| {scale:.3g}, |carried - plain| {diff:.3g}, floor {floor:.3g}"
        assert floor <= (1e-3 if name in ("x", "v", "F") else 2e-2) * scale, report  # the test can resolve
        diff_inside = np.abs(plain_inside[name] - carried_inside[name]).max()
        if device == "cpu":
            assert np.array_equal(plain[name], again[name]), report  # deterministic
            assert np.array_equal(plain[name], carried[name]), report  # bit-identical
            assert np.array_equal(plain_inside[name], carried_inside[name]), f"{report} (re-sort inside)"
        else:
            assert diff <= CARRY_NOISE_FACTOR * floor + 1e-6 * scale, report
            assert diff_inside <= CARRY_NOISE_FACTOR * floor + 1e-6 * scale, \
                f"{report}, re-sort inside {diff_inside:.3g}"
    with pytest.raises(ValueError, match="carry_affine"):
        MPMSolver(p, scene, device, p2g="chunked", sort_every=1, carry_affine=True)
