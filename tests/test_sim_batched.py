"""Batched simulation (sim/batch.py): K runs in one launch must equal K separate runs.

The independent reference is the unbatched MPMSolver (its physics is tested against analytic
answers in test_sim_physics.py): every run of a batch — different forces, stiffness, substep
counts, impulses, fixed parts, plasticity — is compared frame by frame with the same model run
alone (particles in the same order, so on the CPU the bits agree). Runs on every Warp device
present (cpu always, cuda when a GPU is there)."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from pixie_gs.diagnose.forward import Fidelity, ForwardModel
from pixie_gs.diagnose.measured import tracks_from_arrays
from pixie_gs.diagnose.pipeline import DiagnoseOptions, diagnose
from pixie_gs.diagnose.synthetic import make_measurement, toss_scene, two_part_block
from pixie_gs.errors import ComputationError, InputError
from pixie_gs.materials import JELLY, METAL
from pixie_gs.sim import MPMSolver, Particles, Scene
from pixie_gs.sim.batch import BatchedSolver, simulate_batch
from pixie_gs.sim.run import simulate
from test_sim_kernels import device  # noqa: F401  (the per-device fixture)

BASE = {"domain": {"size_m": 1.0, "grid": 20}, "ground": {"friction": 0.3},
        "impulses": [{"time_s": 0.0, "velocity_change": [1.5, 0.0, 1.0]}]}


def scene_with(**keys: object) -> Scene:
    d = copy.deepcopy(BASE)
    d.update(keys)
    return Scene.from_dict(d)


def block(E: float = 1e4, **attrs: object) -> Particles:
    attrs = {"nu": 0.3, "density": 500.0, "material_id": JELLY, **attrs}
    p = Particles.lattice((-0.08, -0.06, 0.05), (0.08, 0.06, 0.15), 0.025, E=E, **attrs)
    p.part_id = (p.x[:, 2] > 0.1).astype(np.int32)  # two parts: bottom 0, top 1
    return p


def varied_runs() -> list[tuple[Particles, Scene]]:
    metal = block(E=2e5, material_id=METAL, yield_stress=150.0)
    return [
        (block(), scene_with()),
        (block(), scene_with(damping=2.5)),
        (block(), scene_with(air_drag=3.0)),
        (block(), scene_with(ground={"friction": 1.2})),
        (block(), scene_with(wind=[{"acceleration": [0.0, 3.0, 0.0], "gust_amplitude": 0.5,
                                    "gust_frequency_hz": 3.0, "start_s": 0.05},
                                   {"acceleration": [-2.0, 0.0, 0.0], "region": {"min": [-1, -1, -1],
                                                                                 "max": [1, 1, 0.12]}}])),
        (block(E=2e5), scene_with()),  # stiffer: about 4× the substeps of the others
        (block(), scene_with(fixed=[{"part_ids": [0]}])),  # bottom held: the top swings
        (metal, scene_with(impulses=[{"time_s": 0.04, "velocity_change": [0.0, 0.0, -4.0],
                                      "region": {"min": [-1, -1, 0.1], "max": [1, 1, 1]}}])),
        (block(), scene_with(gravity=[0.0, 0.0, -3.0])),
    ]


def tol(device: str) -> float:
    """CPU: bit-identical (same arithmetic, threads in order); CUDA: atomics add in any order."""
    return 0.0 if device == "cpu" else 2e-3


def test_batched_runs_equal_separate_runs(device):
    runs = varied_runs()
    batch = BatchedSolver(runs, device)
    alone = [MPMSolver(p, sc, device, sort_every=0, p2g="atomic") for p, sc in runs]
    for _ in range(6):
        batch.step_frame(1.0 / 25)
        for r, sim in enumerate(alone):
            sim.step_frame(1.0 / 25)
            assert batch.substeps_last_frame[r] == sim.substeps_last_frame
            np.testing.assert_allclose(batch.positions(r), sim.positions(), rtol=0, atol=tol(device),
                                       err_msg=f"run {r}")
    for r, sim in enumerate(alone):
        np.testing.assert_allclose(batch.velocities(r), sim.velocities(), rtol=0, atol=20 * tol(device))
        np.testing.assert_allclose(batch.deformation_gradients(r), sim.deformation_gradients(), rtol=0,
                                   atol=20 * tol(device))
    subs = batch.substeps_last_frame
    assert subs[5] > 2 * subs[0]  # the stiff run really took its own, smaller dt
    moved = [np.abs(batch.positions(r) - p.x).max() for r, (p, _) in enumerate(runs)]
    free = [m for r, m in enumerate(moved) if r != 6]
    assert min(free) > 0.02 and np.ptp(free) > 0.01  # every free run moved, and not all alike
    held = runs[6][0].part_id == 0
    np.testing.assert_array_equal(batch.positions(6)[held], runs[6][0].x[held])  # the held part stays put


def test_a_diverging_run_stops_alone_and_the_others_go_on(device):
    # two halves thrown into each other at 60 m/s with at most 4 substeps a frame: F collapses
    keys = {"solver": {"max_substeps_per_frame": 4}}
    clash = scene_with(impulses=[{"time_s": 0.0, "velocity_change": [60.0, 0.0, 0.0],
                                  "region": {"min": [-1, -1, -1], "max": [0.0, 1, 1]}},
                                 {"time_s": 0.0, "velocity_change": [-60.0, 0.0, 0.0],
                                  "region": {"min": [0.0, -1, -1], "max": [1, 1, 1]}}], **keys)
    runs = [(block(E=100.0), scene_with(**keys)), (block(E=100.0), clash),
            (block(E=100.0), scene_with(damping=1.0, **keys))]
    batch = BatchedSolver(runs, device)
    alone = MPMSolver(*runs[1], device, sort_every=0)
    with pytest.raises(ComputationError, match="diverged") as raised:
        for _ in range(4):
            alone.step_frame(1.0 / 25)
    for _ in range(4):
        batch.step_frame(1.0 / 25)
    assert [e is None for e in batch.errors] == [True, False, True]
    assert str(batch.errors[1]).split(":")[0] == str(raised.value).split(":")[0]  # same frame and time
    for r in (0, 2):
        sim = MPMSolver(*runs[r], device, sort_every=0, p2g="atomic")
        for _ in range(4):
            sim.step_frame(1.0 / 25)
        np.testing.assert_allclose(batch.positions(r), sim.positions(), rtol=0, atol=tol(device))


def test_a_run_over_the_substep_budget_is_run_alone(device):
    """A part too stiff for the budget is the unbatched solver's call (rigid body or softened):
    the batch stops that run and simulate_batch hands it to sim.run.simulate."""
    cloud = two_part_block(200, seed=2)
    scene = toss_scene()
    scene.solver.max_substeps_per_frame = 12
    stiff = cloud.copy()
    stiff.set("E", np.full(len(cloud), 5e6, np.float32), np.float32)
    batch = BatchedSolver([(block(), scene_with(solver={"max_substeps_per_frame": 12})),
                           (block(E=5e6), scene_with(solver={"max_substeps_per_frame": 12}))], device)
    batch.step_frame(1.0 / 25)
    assert batch.over_budget == [False, True] and batch.errors == [None, None]
    trajs = simulate_batch([(cloud, scene), (stiff, scene)], 6, 25.0, device=device)
    ref = simulate(stiff, scene, 6, 25.0, device=device, quiet=True)
    np.testing.assert_allclose(trajs[1].x, ref.x, rtol=0, atol=tol(device))


def test_runs_on_different_grids_are_refused():
    with pytest.raises(InputError, match="same grid"):
        BatchedSolver([(block(), scene_with()), (block(), scene_with(domain={"size_m": 1.0, "grid": 24}))])


def test_simulate_batch_matches_simulate_per_model(device):
    """Cloud-level API: same placement and output frames as sim.run.simulate (which sorts the
    particles by cell: float rounding differs, so a tolerance of 0.1 mm over 12 frames)."""
    cloud = two_part_block(300, seed=1)
    scene = toss_scene()
    drag = copy.deepcopy(scene)
    drag.air_drag = 2.0
    trajs = simulate_batch([(cloud, scene), (cloud, drag)], 12, 25.0, device=device)
    for traj, sc in zip(trajs, (scene, drag)):
        ref = simulate(cloud, sc, 12, 25.0, device=device, quiet=True)
        np.testing.assert_allclose(traj.t, ref.t)
        assert traj.substeps_per_frame == ref.substeps_per_frame
        np.testing.assert_allclose(traj.x, ref.x, rtol=0, atol=1e-4)
    assert np.abs(trajs[0].x[-1] - trajs[1].x[-1]).max() > 5e-3
    ids = np.array([5, 0, 299, 17])  # only these Gaussians, in this order
    picked = simulate_batch([(cloud, scene), (cloud, drag)], 12, 25.0, device=device, points=ids)
    for full, part in zip(trajs, picked):
        np.testing.assert_allclose(part.x, full.x[:, ids], rtol=0, atol=tol(device))


def test_forward_model_batched_predictions_equal_one_by_one(device):
    cloud = two_part_block(300, seed=0)
    scene = toss_scene()
    arrays = make_measurement(cloud, scene, 10, 25.0, "air_drag", None, {"k_per_m": 2.0}, fraction=0.1,
                              seed=3, device=device)
    tracks = tracks_from_arrays(arrays["t"], arrays["x"], cloud, ids=arrays["ids"])
    variants = []
    for k in (0.5, 1.0, 4.0):
        sc = copy.deepcopy(scene)
        sc.air_drag = k
        variants.append((sc, None))
    one = ForwardModel(cloud, tracks, device=device, batch=False)
    many = ForwardModel(cloud, tracks, device=device, batch=True)
    ref = [one.predict(sc, c) for sc, c in variants]
    got = many.predict_many(variants + variants[:1])  # a duplicate is simulated once
    assert many.runs == 3 and many.batches == 1
    for a, b in zip(got, ref + ref[:1]):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-4)


def test_reduced_baseline_rides_in_the_first_prediction_batch():
    """set_baseline runs only the full model; the reduced run of θ₀ goes out with the first
    prediction's variants (one batch) and gives the same delta-corrected prediction as when it is
    made alone first; a baseline replaced before any prediction never costs a reduced run."""
    cloud = two_part_block(400, seed=0)
    scene = toss_scene()
    arrays = make_measurement(cloud, scene, 8, 25.0, "air_drag", None, {"k_per_m": 2.0}, fraction=0.1,
                              seed=3, device="cpu")
    tracks = tracks_from_arrays(arrays["t"], arrays["x"], cloud, ids=arrays["ids"])
    fid = Fidelity(max_particles=200, min_grid=16)
    variant = copy.deepcopy(scene)
    variant.air_drag = 1.0
    lazy = ForwardModel(cloud, tracks, device="cpu", batch=True, fidelity=fid)
    assert lazy.is_reduced
    other = copy.deepcopy(scene)
    other.air_drag = 3.0
    lazy.set_baseline(other)                  # replaced before use: its reduced run is never made
    lazy.set_baseline(scene)
    assert (lazy.runs, lazy.batches) == (2, 2)
    got = lazy.predict(variant)
    assert (lazy.runs, lazy.batches) == (4, 3)  # θ₀'s reduced run and the variant's: one batch
    alone = ForwardModel(cloud, tracks, device="cpu", batch=True, fidelity=fid)
    alone.set_baseline(scene)
    alone.predict(scene)                      # θ₀'s reduced run first, on its own
    np.testing.assert_allclose(got, alone.predict(variant), rtol=0, atol=1e-6)


def test_batched_diagnosis_names_the_hidden_effect():
    """The whole loop with every stage's runs batched (CPU: the CPU default is unbatched)."""
    cloud = two_part_block(300, seed=0)
    scene = toss_scene()
    arrays = make_measurement(cloud, scene, 15, 25.0, "wind", None,
                              {"ax_m_s2": 0.0, "ay_m_s2": 2.0, "az_m_s2": 0.0}, fraction=0.1, noise_m=1e-3,
                              seed=7, device="cpu")
    tracks = tracks_from_arrays(arrays["t"], arrays["x"], cloud, ids=arrays["ids"])
    d = diagnose(cloud, scene, tracks, device="cpu",
                 options=DiagnoseOptions(solver_floor=False, batch=True, max_effects=1))
    assert d.effect is not None and d.effect.effect == "wind"
    assert d.effect.params["ay_m_s2"] == pytest.approx(2.0, abs=0.4)
    assert d.gap_after < 0.3 * d.gap_before


def test_cuda_graph_replay_equals_plain_launches(device):
    """On a GPU a substep's launches can be replayed as one captured CUDA graph (graph=True):
    same runs, same substeps, same tracks (to atomic-order rounding) as plain launches."""
    if device == "cpu":
        pytest.skip("CUDA graphs exist on GPUs only")
    runs = varied_runs()
    replayed = BatchedSolver(runs, device, graph=True)
    launched = BatchedSolver(runs, device, graph=False)
    assert replayed.graph is not None and launched.graph is None
    assert replayed.graph_unrolled is not None  # frames 2-4 (no impulse pending) replay it: ≥ 11 substeps each
    for _ in range(4):
        replayed.step_frame(1.0 / 25)
        launched.step_frame(1.0 / 25)
        assert replayed.substeps_last_frame == launched.substeps_last_frame
        for r in range(len(runs)):
            np.testing.assert_allclose(replayed.positions(r), launched.positions(r), rtol=0, atol=tol(device))
    assert np.abs(replayed.positions(0) - runs[0][0].x).max() > 0.02


def test_close_rivals_on_the_reduced_model_are_settled_on_the_full_model(monkeypatch, capsys):
    """Reduced-model fitting (a subset on a coarser grid): rivals of the winner are polished on
    the full model too and the smallest full-model SSE is added — here every significant rival is
    checked (RIVAL_WITHIN = 1), batched, and hidden drag must still win with the smallest SSE."""
    import pixie_gs.diagnose.pipeline as pipeline
    from pixie_gs.diagnose.forward import Fidelity
    from pixie_gs.progress import set_quiet

    monkeypatch.setattr(pipeline, "RIVAL_WITHIN", 1.0)
    cloud = two_part_block(300, seed=0)
    scene = toss_scene()
    arrays = make_measurement(cloud, scene, 15, 25.0, "air_drag", None, {"k_per_m": 2.0}, noise_m=1e-3,
                              fraction=0.1, seed=4, device="cpu")
    tracks = tracks_from_arrays(arrays["t"], arrays["x"], cloud, ids=arrays["ids"])
    options = DiagnoseOptions(effects=["air_drag", "viscous_damping", "wind"], max_effects=1, solver_floor=False,
                              batch=True, fidelity=Fidelity(max_particles=200, grid_scale=0.6, min_grid=12))
    set_quiet(False)
    try:
        d = diagnose(cloud, scene, tracks, device="cpu", options=options)
    finally:
        set_quiet(True)
    line = next(s for s in capsys.readouterr().err.splitlines() if "full-model check of close rivals" in s)
    sses = {name.strip(): float(v) for name, v in
            (part.rsplit(" SSE ", 1) for part in line.split(": ", 1)[1].split(" → ")[0].split(", "))}
    assert len(sses) >= 2 and "air_drag" in sses
    assert d.effect is not None and d.effect.effect == "air_drag" and line.endswith("→ air_drag")
    assert sses["air_drag"] == min(sses.values()) and d.effect.sse == pytest.approx(sses["air_drag"], rel=1e-3)
    assert d.rounds[0].ranking[0].effect == "air_drag"
    assert d.gap_after <= 0.2 * d.gap_before


def test_substep_plan_of_all_runs_equals_the_per_run_rule():
    """BatchedSolver._plan (every run at once, numpy) gives _substeps' count for each run (the
    per-run reference): random speeds and snow waves, pending impulses, a run over the budget."""
    from pixie_gs.materials import SNOW

    snow = block(E=3e4, material_id=SNOW)
    runs = varied_runs() + [(snow, scene_with()), (block(E=5e10), scene_with())]
    batch = BatchedSolver(runs, "cpu")
    rng = np.random.default_rng(3)
    for trial in range(40):
        if trial == 20:
            batch.step_frame(1.0 / 25)  # the t = 0 impulses are spent; one run's impulse still pending
        maxima = np.stack([rng.uniform(0.0, 30.0, len(runs)), rng.uniform(0.0, 400.0, len(runs))], axis=1)
        maxima[rng.random(len(runs)) < 0.2] = 0.0
        frame_dt = float(rng.choice([1 / 25, 1 / 30, 1 / 60, 0.1]))
        planned = batch._plan(frame_dt, maxima)
        alive = batch.alive
        rule = [batch._substeps(r, frame_dt, float(maxima[r, 0]), float(maxima[r, 1])) if alive[r] else 0
                for r in range(len(runs))]
        assert planned.tolist() == rule
    assert 0 in rule and max(rule) > 1  # the over-budget run, and runs needing several substeps


def test_grids_are_clear_after_every_frame(device):
    """step_frame does not clear the grids: each grid launch clears the nodes it read, which must
    be every node P2G touched (runs with fewer substeps, a stopped run, the CPU's active box)."""
    runs = varied_runs()[:6]
    batch = BatchedSolver(runs, device)
    for _ in range(3):
        batch.step_frame(1.0 / 25)
        for grid in (batch.grid_mass, batch.grid_momentum, batch.grid_fixed):
            assert not np.any(grid.numpy())


def test_frames_on_the_device_equal_step_frame(device):
    """DeviceFrames (plan, substep loop, statistics, guard and tracked points all on the device, one
    read-back at the end) takes step_frame's substeps: the same positions (CPU: bit for bit),
    substep counts, dt, clock and host bookkeeping afterwards."""
    from pixie_gs.sim.device_frames import DeviceFrames, device_loop_available

    if not device_loop_available(device):
        pytest.skip("no conditional CUDA graphs here (CUDA 12.4+)")
    runs = varied_runs()
    stepped, looped = BatchedSolver(runs, device), BatchedSolver(runs, device)
    for _ in range(3):  # the last impulse (run 7, t = 0.04 s) is applied by then
        stepped.step_frame(1.0 / 25)
        looped.step_frame(1.0 / 25)
    slots = np.arange(looped.n)
    history = DeviceFrames(looped, 1.0 / 25, slots, 10).run(5)
    for i in range(5):
        stepped.step_frame(1.0 / 25)
        np.testing.assert_allclose(history[i], stepped.positions(), rtol=0, atol=tol(device), err_msg=f"frame {i}")
    assert looped.substeps_last_frame == stepped.substeps_last_frame
    assert looped.frame == stepped.frame == 8 and looped.time_s == stepped.time_s
    assert looped.substeps_total == stepped.substeps_total
    assert [looped.dt(r) for r in range(len(runs))] == [stepped.dt(r) for r in range(len(runs))]
    np.testing.assert_allclose(looped.positions(), stepped.positions(), rtol=0, atol=tol(device))
    looped.step_frame(1.0 / 25)  # the host loop carries on from the device's frames
    stepped.step_frame(1.0 / 25)
    np.testing.assert_allclose(looped.positions(), stepped.positions(), rtol=0, atol=tol(device))


def test_device_loop_stops_diverging_and_over_budget_runs_as_step_frame_does(device):
    """simulate_batch with the frames on the device: a run that diverges gets step_frame's error
    (same frame, time and counts), a run over the substep budget is run alone, the others match."""
    from pixie_gs.sim.device_frames import device_loop_available

    if not device_loop_available(device):
        pytest.skip("no conditional CUDA graphs here (CUDA 12.4+)")
    cloud = two_part_block(300, seed=3)
    still = {"object": {"size_m": 0.3, "position": [-0.15, 0.0, 0.1]}, "domain": {"size_m": 1.0, "grid": 20},
             "solver": {"max_substeps_per_frame": 40}}  # no impulse: every frame on the device
    scene = Scene.from_dict(still)
    stiff = cloud.copy()  # over the budget at the device's first plan
    stiff.set("E", np.full(len(cloud), 5e6, np.float32), np.float32)
    wild = Scene.from_dict({**still, "wind": [{"acceleration": [3000.0, 0.0, 0.0], "start_s": 0.1}]})
    drag = Scene.from_dict({**still, "air_drag": 2.0, "gravity": [0.0, 0.0, -30.0]})
    models = [(cloud, scene), (stiff, scene), (cloud, wild), (cloud, drag)]
    ids = np.arange(0, 300, 7)
    host = simulate_batch(models, 12, 25.0, device=device, points=ids, device_loop=False)
    loop = simulate_batch(models, 12, 25.0, device=device, points=ids, device_loop=True)
    assert isinstance(host[2], ComputationError) and str(loop[2]) == str(host[2])
    assert "diverged at frame 3 " in str(host[2])  # the wind starts at 0.1 s: a device frame's guard
    for r in (0, 1, 3):
        np.testing.assert_allclose(loop[r].x, host[r].x, rtol=0, atol=tol(device))
        assert (loop[r].dt_s, loop[r].substeps_per_frame) == (host[r].dt_s, host[r].substeps_per_frame)
