"""Stiff parts (sim/rigid.py) against answers the solver does not produce: a part too stiff for the
substep budget moves as a rigid body (relative distances kept to float precision, free fall
½gt² and the exact symplectic-Euler sum, torque-free spin at constant ω), presses an elastic
pad as its weight says (static compression vs load·H/(E·A)), comes to rest on the ground (a
tilted cube landing on an edge tips back flat) and on fixed material, and trades momentum with
soft material without creating any; the per-part choice is printed with
the substeps the P-wave speed needs; "soften" and "true" do what they say.
The soda can: on CUDA at true stiffness it dents and stays dented; on the CPU it runs rigid.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pytest

from pixie_gs.errors import InputError
from pixie_gs.materials import JELLY, METAL, SAND, STATIONARY
from pixie_gs.sim import MPMSolver, Particles, Scene
from pixie_gs.sim.can_scene import diameter_along_blow, soda_can
from test_sim_kernels import device  # noqa: F401  (the per-device fixture)
from test_sim_physics import join

G = 9.81  # m/s²


@pytest.fixture(autouse=True)
def stage_lines_on():
    """The per-part lines are stage() lines: print them here whatever an earlier test set."""
    from pixie_gs import progress

    quiet = progress.is_quiet()
    progress.set_quiet(False)
    yield
    progress.set_quiet(quiet)
AL = {"E": 7e10, "nu": 0.33, "density": 2700.0, "material_id": METAL}  # aluminium


def p_wave(E: float, nu: float, rho: float) -> float:
    """Textbook P-wave speed (m/s)."""
    return math.sqrt(E * (1 - nu) / (rho * (1 + nu) * (1 - 2 * nu)))


def pair_distances(x: np.ndarray, k: int = 60) -> np.ndarray:
    idx = np.linspace(0, len(x) - 1, k).astype(int)
    return np.linalg.norm(x[idx, None] - x[None, idx], axis=-1)


def free_scene(**extra: object) -> Scene:
    keys = {"domain": {"size_m": 0.8, "grid": 24, "origin": [-0.4, -0.4, -0.55]}, "ground": {"enabled": False},
            "solver": {"max_substeps_per_frame": 60, "velocity_cfl": 0.1}}
    keys.update(extra)
    return Scene.from_dict(keys)


# ---------------------------------------------------------------------------------------- rigid motion
def test_stiff_block_falls_as_a_rigid_body_and_says_why(device, capsys):
    scene = free_scene()
    p = Particles.lattice((-0.06, -0.06, 0.1), (0.06, 0.06, 0.2), scene.dx / 2, **AL)
    sim = MPMSolver(p, scene, device)
    fall = 0.0  # symplectic Euler, substep by substep: v += g·dt, x += v·dt
    v = 0.0
    for _ in range(8):
        sim.step_frame(1 / 30)
        dt = (1 / 30) / sim.substeps_last_frame
        for _ in range(sim.substeps_last_frame):
            v += G * dt
            fall += v * dt
    x = sim.positions()
    drop = float(p.x[:, 2].mean() - x[:, 2].mean())
    assert drop == pytest.approx(fall, rel=1e-4)
    assert drop == pytest.approx(0.5 * G * sim.time_s ** 2, rel=0.02)
    assert np.abs(pair_distances(x) - pair_distances(p.x)).max() < 1e-6  # float32 precision on 0.2 m
    assert np.allclose(sim.deformation_gradients(), np.eye(3), atol=1e-4)  # F = R = I up to float noise
    # the choice, with the substeps the aluminium P-wave needs (c·frame_dt / (cfl·dx))
    need = math.ceil((1 / 30) * p_wave(7e10, 0.33, 2700.0) / (scene.solver.cfl * scene.dx))
    (choice,) = sim.stiff_part_choices
    assert (choice.choice, choice.substeps_needed, choice.budget) == ("rigid", need, 60)
    assert f"body (metal, {len(p):,} particles): E 7e+10 Pa needs {need:,} substeps/frame, budget 60 → rigid" \
        in capsys.readouterr().err
    assert sim.stiffness_scale == 1.0  # nothing softened


def test_spinning_rigid_body_keeps_omega_and_turns_by_omega_t(device):
    scene = free_scene(gravity=[0, 0, 0])
    p = Particles.lattice((-0.06, -0.06, -0.06), (0.06, 0.06, 0.06), scene.dx / 2, **AL)
    omega = np.array([0.0, 0.0, 6.0])  # rad/s about z through the centre (a principal axis of the cube)
    p.v = np.cross(omega, p.x).astype(np.float32)
    sim = MPMSolver(p, scene, device)
    for _ in range(6):
        sim.step_frame(1 / 30)
    angle = 6.0 * sim.time_s
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    # torque-free: the centre of mass drifts at its initial velocity, the body turns about it
    com = p.x.astype(np.float64).mean(0)
    expected = com + np.cross(omega, com) * sim.time_s + (p.x - com) @ rot.T
    assert np.abs(sim.positions() - expected).max() < 1e-5
    assert sim.rigid.state()["omega"][0] == pytest.approx(omega, abs=1e-4)
    F = sim.deformation_gradients()  # F = R: the Gaussians' covariances turn with the body
    assert np.allclose(F, rot, atol=1e-5)


def test_rigid_and_soft_block_collide_without_creating_momentum(device):
    scene = free_scene(gravity=[0, 0, 0])
    rigid = Particles.lattice((-0.2, -0.05, -0.05), (-0.1, 0.05, 0.05), scene.dx / 2, v=[2.0, 0, 0], **AL)
    soft = Particles.lattice((-0.06, -0.05, -0.05), (0.04, 0.05, 0.05), scene.dx / 2, E=2e4, nu=0.3,
                             density=1000.0, material_id=JELLY)
    both = join(rigid, soft)
    m = both.mass.astype(np.float64)
    p0 = (m[:, None] * both.v).sum(0)
    sim = MPMSolver(both, scene, device)
    for _ in range(6):
        sim.step_frame(1 / 60)
    v = sim.velocities().astype(np.float64)
    n_r = len(rigid)
    assert (m[:, None] * v).sum(0) == pytest.approx(p0, abs=1e-4 * np.abs(p0).max())
    soft_p = (m[n_r:] * v[n_r:, 0]).sum()
    assert soft_p > 0.2 * p0[0]  # the hit went into the soft block...
    assert np.abs(pair_distances(sim.positions()[:n_r]) - pair_distances(rigid.x)).max() < 1e-6  # ...not the rigid
    assert [c.choice for c in sim.stiff_part_choices] == ["rigid"]


def test_rigid_block_on_a_jelly_pad_compresses_it_as_its_weight_says(device):
    """Static load: a rigid block of mass M on a pad (height H, area A, Young's modulus E, ν = 0
    so no lateral bulge) shortens it by δ = (M·g/A + ρ_pad·g·H/2)·H/E."""
    scene = Scene.from_dict({"domain": {"size_m": 0.4, "grid": 20}, "damping": 15.0,
                             "ground": {"enabled": True, "friction": 0.0},
                             "solver": {"max_substeps_per_frame": 150}})
    h = scene.dx / 2
    E_pad, rho_pad, H, side = 2e4, 100.0, 0.1, 0.1
    pad = Particles.lattice((-side / 2, -side / 2, 0.0), (side / 2, side / 2, H), h, E=E_pad, nu=0.0,
                            density=rho_pad, material_id=JELLY)
    block = Particles.lattice((-side / 2, -side / 2, H), (side / 2, side / 2, H + 0.05), h, **{**AL, "density": 2000.0})
    sim = MPMSolver(join(pad, block), scene, device)
    for _ in range(30):
        sim.step_frame(1 / 30)
    x = sim.positions()
    n = len(pad)
    M = block.mass.astype(np.float64).sum()
    delta = (M * G / side ** 2 + rho_pad * G * H / 2) * H / E_pad
    assert pad.x[:, 2].max() - x[:n, 2].max() == pytest.approx(delta, rel=0.2)  # the pad's top came down by δ
    gap0 = block.x[:, 2].min() - pad.x[:, 2].max()
    assert x[n:, 2].min() - x[:n, 2].max() == pytest.approx(gap0, abs=1e-3)  # the block rests on it, not sinking in
    assert np.abs(sim.velocities()).max() < 0.02  # at rest
    assert [c.choice for c in sim.stiff_part_choices] == ["rigid"]


def test_rigid_block_lands_and_rests_on_the_ground(device):
    scene = Scene.from_dict({"domain": {"size_m": 0.5, "grid": 20}, "solver": {"max_substeps_per_frame": 30}})
    p = Particles.lattice((-0.05, -0.05, 0.1), (0.05, 0.05, 0.15), scene.dx / 2, **AL)
    sim = MPMSolver(p, scene, device)
    for _ in range(15):  # 0.1 m fall takes 0.14 s; then 0.36 s resting
        sim.step_frame(1 / 30)
    z = sim.positions()[:, 2]
    lowest0 = p.x[:, 2].min() - 0.1  # where its lowest particles sit when touching z = 0
    assert z.min() >= -1e-6 and z.min() - lowest0 < scene.dx  # on the ground, not sunk, not floating
    assert np.abs(sim.velocities()).max() < 1e-3


def test_tilted_rigid_cube_lands_on_an_edge_and_tips_back_flat(device):
    """A cube tilted 30° about x (less than 45°: its centre of mass is over the edge it lands
    on) falls 2 cm, lands on that edge and tips back onto its face: flat, at rest, above ground."""
    scene = Scene.from_dict({"domain": {"size_m": 0.5, "grid": 20}, "damping": 2.0, "ground": {"friction": 0.8},
                             "solver": {"max_substeps_per_frame": 30}})
    a = math.radians(30.0)
    rot = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    cube = Particles.lattice((-0.05, -0.05, -0.05), (0.05, 0.05, 0.05), scene.dx / 2, **AL)
    x = cube.x @ rot.T
    cube.x = (x + [0, 0, 0.02 - x[:, 2].min()]).astype(np.float32)
    sim = MPMSolver(cube, scene, device)
    for _ in range(30):
        sim.step_frame(1 / 30)
    q = sim.rigid.state()["quat"][0]
    tilt = math.degrees(2 * math.asin(min(1.0, float(np.linalg.norm(q[:3])))))  # of the body, from its start
    assert abs(tilt - 30.0) < 2.0  # turned back by the 30° it was tilted
    z = sim.positions()[:, 2]
    assert z.min() > -0.1 * scene.dx and z.min() < 0.5 * scene.dx
    assert np.abs(sim.velocities()).max() < 0.01


def test_rigid_block_rests_on_a_fixed_slab_instead_of_sinking_into_it(device):
    scene = Scene.from_dict({"domain": {"size_m": 0.5, "grid": 20}, "solver": {"max_substeps_per_frame": 30}})
    h = scene.dx / 2
    slab = Particles.lattice((-0.1, -0.1, 0.0), (0.1, 0.1, 0.05), h, E=1e6, nu=0.3, density=500.0,
                             material_id=STATIONARY, part_id=0)
    block = Particles.lattice((-0.05, -0.05, 0.05), (0.05, 0.05, 0.1), h, part_id=1, **AL)  # another part: not held
    sim = MPMSolver(join(slab, block), scene, device)
    for _ in range(10):
        sim.step_frame(1 / 30)
    assert [c.choice for c in sim.stiff_part_choices] == ["rigid"]
    assert np.abs(sim.positions()[len(slab):] - block.x).max() < 1e-4  # resting where it was put


# ---------------------------------------------------------------------------------------- choices
def test_each_part_gets_its_own_choice(device, capsys):
    """Metal part → rigid; a sand part over budget flows, so it is softened; a jelly part that fits
    keeps true stiffness and is not mentioned; a stiff part touching fixed particles is held."""
    scene = free_scene(gravity=[0, 0, -9.81])
    h = scene.dx / 2
    metal = Particles.lattice((-0.25, -0.05, 0.0), (-0.15, 0.05, 0.1), h, part_id=1, **AL)
    sand = Particles.lattice((-0.05, -0.05, 0.0), (0.05, 0.05, 0.1), h, E=5e8, nu=0.3, density=2000.0,
                             material_id=SAND, part_id=2)
    jelly = Particles.lattice((0.15, -0.05, 0.0), (0.25, 0.05, 0.1), h, E=1e4, nu=0.3, density=500.0,
                              material_id=JELLY, part_id=3)
    bracket = Particles.lattice((-0.05, 0.15, 0.0), (0.05, 0.25, 0.1), h, part_id=4, **AL)
    bracket.fixed[bracket.x[:, 1] > 0.22] = True  # its far end is held
    sim = MPMSolver(join(metal, sand, jelly, bracket), scene, device)
    sim.step_frame(1 / 30)
    got = {c.label: c.choice for c in sim.stiff_part_choices}
    assert got == {"part 1": "rigid", "part 2": "soften", "part 4": "held"}
    err = capsys.readouterr().err
    assert "part 2 (sand" in err and "→ softened to" in err and "part 3" not in err
    c_allowed = scene.solver.cfl * scene.dx * 60 / (1 / 30)
    sand_scale = next(c.E_scale for c in sim.stiff_part_choices if c.label == "part 2")
    assert p_wave(5e8 * sand_scale, 0.3, 2000.0) <= c_allowed  # softened just enough to fit
    n1, n2, n3 = len(metal), len(sand), len(jelly)
    x = sim.positions()
    assert np.abs(x[n1 + n2 + n3:] - bracket.x).max() == 0.0  # held as a whole
    assert x[:n1, 2].mean() < metal.x[:, 2].mean()  # the rigid part falls


def test_auto_softens_a_part_that_almost_fits_and_soften_mode_keeps_the_old_cap(device):
    scene = free_scene()
    p = Particles.lattice((-0.05, -0.05, 0.0), (0.05, 0.05, 0.1), scene.dx / 2, E=2e6, nu=0.3, density=1000.0,
                          material_id=JELLY)
    c = p_wave(2e6, 0.3, 1000.0)
    need = math.ceil((1 / 30) * c / (scene.solver.cfl * scene.dx))
    assert 60 < need < 60 * math.sqrt(10)  # over budget, but fits when E is lowered by less than 10×
    sim = MPMSolver(p, scene, device)
    sim.step_frame(1 / 30)
    assert [ch.choice for ch in sim.stiff_part_choices] == ["soften"] and sim.rigid is None
    assert sim.stiffness_scale == pytest.approx(0.999 * (60 / ((1 / 30) * c / (scene.solver.cfl * scene.dx))) ** 2,
                                                rel=1e-4)
    stiff = Particles.lattice((-0.05, -0.05, 0.0), (0.05, 0.05, 0.1), scene.dx / 2, **AL)
    sim = MPMSolver(stiff, free_scene(solver={"max_substeps_per_frame": 60, "stiff_parts": "soften"}), device)
    sim.step_frame(1 / 30)
    assert sim.rigid is None and sim.stiffness_scale < 1e-4 and sim.stiff_part_choices[0].choice == "soften"


def test_true_mode_refuses_to_change_a_material(device):
    scene = free_scene(solver={"max_substeps_per_frame": 60, "stiff_parts": "true"})
    sim = MPMSolver(Particles.lattice((-0.05, -0.05, 0.0), (0.05, 0.05, 0.1), scene.dx / 2, **AL), scene, device)
    need = math.ceil((1 / 30) * p_wave(7e10, 0.33, 2700.0) / (scene.solver.cfl * scene.dx))
    with pytest.raises(InputError, match=rf"needs {need:,} substeps/frame, budget 60 but solver.stiff_parts is "
                                         rf"\"true\": raise solver.max_substeps_per_frame to {need}"):
        sim.step_frame(1 / 30)


def test_true_mode_within_the_budget_runs_true_stiffness_and_reports_the_budget_used(device, capsys):
    scene = free_scene(gravity=[0, 0, 0], solver={"max_substeps_per_frame": 500, "stiff_parts": "true"})
    p = Particles.lattice((-0.05, -0.05, 0.0), (0.05, 0.05, 0.1), scene.dx / 2, E=1e7, nu=0.3, density=1000.0,
                          material_id=JELLY, part_id=7)
    sim = MPMSolver(p, scene, device)
    sim.step_frame(1 / 30)
    need = math.ceil((1 / 30) * p_wave(1e7, 0.3, 1000.0) / (scene.solver.cfl * scene.dx))
    assert sim.substeps_last_frame == need and sim.stiffness_scale == 1.0 and sim.rigid is None
    assert f"part 7 (jelly, {len(p):,} particles): E 1e+07 Pa needs {need:,} substeps/frame, budget 500 → true " \
           "stiffness" in capsys.readouterr().err
    sim.step_frame(1 / 30)
    assert len(sim.stiff_part_choices) == 1  # reported once


def test_stiff_parts_key_is_checked():
    with pytest.raises(InputError, match="solver.stiff_parts': must be one of auto, rigid, soften, true"):
        Scene.from_dict({"solver": {"stiff_parts": "jelly"}})
    assert Scene.from_dict({}).solver.stiff_parts == "auto"


# ---------------------------------------------------------------------------------------- soda can
CAN_BLOW_MPS = 150.0  # speed given to the struck patch of the wall (CPU, rigid)
CAN_BLOW_TRUE_MPS = 400.0  # the same at true stiffness: a 2 mm aluminium wall dents ~0.5 mm at 150 m/s (CPU run)


def _cuda_asked() -> bool:
    return "cuda" in os.environ.get("PIXIE_TEST_DEVICES", "cuda")


@pytest.mark.skipif(not _cuda_asked(), reason="PIXIE_TEST_DEVICES leaves CUDA out")
def test_soda_can_dents_and_stays_dented_at_true_stiffness_on_cuda():
    import warp as wp

    from pixie_gs.devices import init_warp_quietly

    init_warp_quietly()
    if not wp.is_cuda_available():
        pytest.skip("no CUDA device")
    p, scene, band = soda_can(dx_m=0.002, dv_mps=CAN_BLOW_TRUE_MPS, stiff_parts="true", budget=100_000)
    sim = MPMSolver(p, scene, "cuda")
    d0 = diameter_along_blow(p.x, band)
    dents = []
    for _ in range(10):  # 10 ms, one frame each
        sim.step_frame(1e-3)
        dents.append(d0 - diameter_along_blow(sim.positions(), band))
    need = math.ceil(1e-3 * p_wave(7e10, 0.33, 2700.0) / (scene.solver.cfl * scene.dx))
    assert sim.substeps_last_frame >= need  # true stiffness: the CFL of real aluminium
    assert [(c.choice, c.substeps_needed) for c in sim.stiff_part_choices] == [("true", need)]  # budget reported
    assert sim.rigid is None and sim.stiffness_scale == 1.0
    dents = np.array(dents)
    print(f"can at true stiffness: {sim.substeps_last_frame:,} substeps/ms (aluminium needs {need:,}); "
          f"dent per ms (mm) {np.round(1000 * dents, 2).tolist()}, diameter {1000 * d0:.1f} mm")
    assert dents[-1] > 0.1 * d0  # dented by more than 10 % of the diameter ...
    assert dents[-1] > 0.8 * dents.max()  # ... and stays dented (spring-back < 20 % of the dent)
    assert np.isfinite(sim.deformation_gradients()).all()


def test_soda_can_runs_as_a_rigid_body_on_a_cpu_budget(capsys):
    """The same can with a CPU budget: never softened. Floating free it is one rigid body, its
    shape kept exactly, moving off with the blow's momentum (Σ m·dv / M); held at its back (as
    on the GPU) it is held as a whole."""
    p, scene, band = soda_can(dx_m=0.004, dv_mps=CAN_BLOW_MPS, stiff_parts="auto", budget=200, held_back=False)
    sim = MPMSolver(p, scene, "cpu")
    for _ in range(2):
        sim.step_frame(1e-3)  # it moves off at ~5 m/s: 1 cm, clear of the domain walls
    assert [c.choice for c in sim.stiff_part_choices] == ["rigid"] and sim.stiffness_scale == 1.0
    assert "part 0 (metal" in capsys.readouterr().err
    x = sim.positions()
    assert np.abs(pair_distances(x) - pair_distances(p.x)).max() < 1e-6
    assert diameter_along_blow(x, band) == pytest.approx(diameter_along_blow(p.x, band), abs=1e-6)
    struck = scene.impulses[0].region.contains(p.x)
    m = p.mass.astype(np.float64)
    v_expected = CAN_BLOW_MPS * m[struck].sum() / m.sum()
    v_mean = (m[:, None] * sim.velocities()).sum(0) / m.sum()
    assert v_mean == pytest.approx([v_expected, 0, 0], abs=1e-3 * v_expected)
    p, scene, band = soda_can(dx_m=0.004, dv_mps=CAN_BLOW_MPS, stiff_parts="auto", budget=200)
    sim = MPMSolver(p, scene, "cpu")
    sim.step_frame(1e-3)
    assert [c.choice for c in sim.stiff_part_choices] == ["held"] and sim.stiffness_scale == 1.0
    assert np.abs(sim.positions() - p.x).max() == 0.0



def test_tilted_slab_landing_on_an_edge_of_many_points_does_not_blow_up(device):
    """A 50 × 47 × 5 cm slab tilted 20° lands on an edge of hundreds of floor contacts at 2.4 m/s (the
    shape and fall of the real pool capture's `drop`, which diverged): with every contact point HEAVY×
    the body the common-motion solve gave the body tens of rad/s and the run was stopped as diverged.
    The contacts now share the weight; the slab lands, stays rigid and above the floor."""
    scene = Scene.from_dict({"domain": {"size_m": 1.2, "grid": 64}, "solver": {"max_substeps_per_frame": 2000}})
    p = Particles.lattice((-0.25, -0.235, 0.0), (0.25, 0.235, 0.05), scene.dx / 2, E=1.5e10, nu=0.3,
                          density=700.0, material_id=JELLY)
    a, b = math.radians(20.0), math.radians(10.0)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    p.x = (((p.x - p.x.mean(axis=0)) @ rx.T) @ ry.T + np.array([0.0, 0.0, 0.35])).astype(np.float32)
    sim = MPMSolver(p, scene, device)
    for _ in range(10):  # lands at ~0.2 s
        sim.step_frame(1 / 24)
    x = sim.positions()
    assert np.isfinite(x).all() and x[:, 2].min() >= -1e-6 and x[:, 2].min() < scene.dx
    np.testing.assert_allclose(pair_distances(x), pair_distances(p.x), atol=1e-4)  # rigid
    assert np.abs(sim.velocities()).max() < 2.4  # slower than it landed: no energy from the contact


def test_one_particle_body_touching_nearly_empty_nodes_keeps_a_finite_motion(device):
    """A rigid body of one particle (no inertia of its own, 6.1 g) covering nodes that hold 5.8e-11 kg of soft
    material: the common-motion solve's matrix has a trace of ~6e-14 kg m² and its float32 inverse came out
    NaN, so ω, v and then the particle's position became NaN and the next P2G indexed outside the grid (a
    segfault; stop 53, a fuzzed splat; the sums below are the ones that substep had). The solve must give a
    finite motion close to the body's free fall (the nodes weigh 1e-8 of it)."""
    import warp as wp

    from pixie_gs.sim.rigid import RigidBodies, rigid_solve

    v0 = np.array([2.2485315e-06, 1.5796262e-06, -0.44536638])
    bodies = RigidBodies(np.array([0]), np.array([[0.0, 0.0, 0.5]]), v0[None], np.array([6.107022e-3]), (4, 4, 4),
                         (0.0, 0.0, -9.81), 0.0, device)
    bodies.omega.assign(np.array([[1.3598376e-04, -5.6772198e-05, 6.2892796e-06]], np.float32))
    sums = {"node_mass": 5.7517352e-11, "node_moment": [8.5209764e-13, 4.3792259e-13, -7.5572795e-13],
            "node_momentum": [2.5866181e-16, 2.4705172e-16, -2.5630244e-11],
            "node_ang": [-1.9513921e-13, 3.7969958e-13, 1.7394351e-18],
            "node_inertia": [[1.5024428e-14, -6.4876566e-15, 1.1195821e-14],
                             [-6.4876566e-15, 2.7602015e-14, 5.7539215e-15],
                             [1.1195821e-14, 5.7539215e-15, 2.2767233e-14]]}
    for name, value in sums.items():
        getattr(bodies, name).assign(np.asarray(value, np.float32)[None])
    dt = 3.28e-6
    wp.launch(rigid_solve, dim=1, device=device,
              inputs=[bodies.body_mass, bodies.inertia0_wp, bodies.inertia_inv0, bodies.kick, bodies.kick_ang,
                      bodies.node_mass, bodies.node_moment, bodies.node_momentum, bodies.node_ang,
                      bodies.node_inertia, bodies.lo, bodies.hi, bodies.com, bodies.pivot, bodies.rot, bodies.vel,
                      bodies.omega, bodies.contacts, bodies.gravity, 0.0, wp.vec3(-9.0, -9.0, -9.0),
                      wp.vec3(9.0, 9.0, 9.0), 0.5, dt])
    state = bodies.state()
    assert all(np.isfinite(state[k]).all() for k in ("com", "quat", "v", "omega"))
    assert state["v"][0] == pytest.approx(v0 + [0.0, 0.0, -9.81 * dt], abs=1e-5)
