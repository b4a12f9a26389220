"""Physics of the Warp MPM (CPU) against known answers: kinematics, elastic waves, Poisson
ratio, contact restitution, plastic set, fixed/stationary parts, forces, covariances, guard.

Grids are coarse and particle counts small so the file runs in a few minutes on 2 cores.
Every test runs on each Warp device present (`device` fixture: cpu, and cuda when a GPU is there).
"""
from __future__ import annotations

import numpy as np
import pytest

from pixie_gs.errors import ComputationError, InputError
from pixie_gs.materials import JELLY, METAL, SAND, SNOW, STATIONARY
from pixie_gs.sim import MPMSolver, Particles, Scene, advect_covariances
from test_sim_kernels import device  # noqa: F401  (the per-device fixture)

G = 9.81  # m/s²


def make_scene(**keys: object) -> Scene:
    return Scene.from_dict(keys)


def join(*parts: Particles) -> Particles:
    """One Particles from several (per-field concatenation)."""
    fields = ("x", "v", "volume", "E", "nu", "density", "material_id", "yield_stress", "fixed", "part_id")
    return Particles(**{f: np.concatenate([getattr(p, f) for p in parts]) for f in fields})


def small_block(scene: Scene, lo=(-0.03, -0.03, 0.0), hi=(0.03, 0.03, 0.06), **attrs: object) -> Particles:
    attrs = {"E": 1e4, "nu": 0.3, "density": 500.0, "material_id": JELLY, **attrs}
    return Particles.lattice(lo, hi, scene.dx / 2, **attrs)


# ---------------------------------------------------------------------------------------- kinematics
def test_free_fall_without_ground_matches_half_g_t_squared(device):
    scene = make_scene(domain={"size_m": 1.0, "grid": 32, "origin": [-0.5, -0.5, -0.7]},
                       ground={"enabled": False}, solver={"velocity_cfl": 0.1})
    p = small_block(scene, lo=(-0.06, -0.06, 0.1), hi=(0.06, 0.06, 0.22))
    sim = MPMSolver(p, scene, device)
    for _ in range(10):
        sim.step_frame(1 / 30)
    drop = p.x[:, 2].mean() - sim.positions()[:, 2].mean()
    assert drop == pytest.approx(0.5 * G * sim.time_s ** 2, rel=0.01)
    # a free body stays undeformed: every particle moved by the same amount
    assert np.ptp(p.x[:, 2] - sim.positions()[:, 2]) < 1e-4


def test_time_step_shrinks_as_snow_compacts_and_hardens(device):
    """Snow's stiffness is E·exp(ξ(1 − Jp)); the CFL step must follow the hardened wave speed."""
    scene = make_scene(domain={"size_m": 1.0, "grid": 32, "origin": [-0.5, -0.5, -0.5]}, ground={"enabled": False},
                       gravity=[0, 0, 0])
    sim = MPMSolver(small_block(scene, E=1e5, density=400.0, material_id=SNOW), scene, device)
    dt_fresh = sim.dt
    jp = np.ones(sim.n, np.float32)
    jp[0] = 0.9  # one grain compacted by 10 %
    sim.set_plastic_volume_ratio(jp)
    xi = scene.materials.snow_hardening
    assert sim.dt == pytest.approx(dt_fresh / np.sqrt(np.exp(xi * 0.1)), rel=1e-5)


def test_substeps_follow_the_cfl_of_the_stiffest_moving_material(device):
    scene = make_scene(domain={"size_m": 1.0, "grid": 32, "origin": [-0.5, -0.5, -0.5]}, ground={"enabled": False},
                       gravity=[0, 0, 0])
    soft = small_block(scene, E=1e4)
    stiff = small_block(scene, lo=(0.1, 0.1, 0.1), hi=(0.15, 0.15, 0.15), E=1e6)
    rigid = small_block(scene, lo=(-0.2, -0.2, -0.2), hi=(-0.15, -0.15, -0.15), E=1e10, material_id=STATIONARY)
    sim = MPMSolver(join(soft, stiff, rigid), scene, device)
    c = np.sqrt(1e6 * 0.7 / (500.0 * 1.3 * 0.4))  # P-wave speed of the stiff block (m/s)
    assert sim.dt == pytest.approx(scene.solver.cfl * scene.dx / c, rel=1e-5)  # stationary part ignored
    assert sim.substeps_for(0.01) == int(np.ceil(0.01 / sim.dt))


# ---------------------------------------------------------------------------------------- elasticity
@pytest.mark.parametrize("E", [1e5, 1e10])  # soft, and stiff as metal (at true stiffness: issue 14)
def test_bar_longitudinal_wave_speed_is_sqrt_E_over_rho(device, E):
    """Free–free bar, first longitudinal mode: period 2L/c with c = √(E/ρ)."""
    scene = make_scene(domain={"size_m": [0.7, 0.2, 0.2], "grid": 56, "origin": [-0.1, -0.1, -0.1]},
                       ground={"enabled": False}, gravity=[0, 0, 0])
    dx, length, rho = scene.dx, 0.5, 1000.0
    t = 2 * dx
    p = Particles.lattice((0, -t / 2, -t / 2), (length, t / 2, t / 2), dx / 2, E=E, nu=0.3, density=rho,
                          material_id=JELLY)
    p.v[:, 0] = 0.005 * np.sqrt(E / rho) * np.cos(np.pi * p.x[:, 0] / length)  # strain amplitude 0.5 %
    left, right = p.x[:, 0] < dx, p.x[:, 0] > length - dx
    sim = MPMSolver(p, scene, device)
    period = 2 * length / np.sqrt(E / rho)
    times, stretch = [0.0], [0.0]
    for _ in range(100):
        sim.step_frame(period / 40)
        x = sim.positions()
        times.append(sim.time_s)
        stretch.append(x[right, 0].mean() - x[left, 0].mean() - (p.x[right, 0].mean() - p.x[left, 0].mean()))
    times, stretch = np.array(times), np.array(stretch)
    i = np.nonzero(stretch[1:-1] * stretch[2:] < 0)[0] + 1
    crossings = times[i] - stretch[i] * (times[i + 1] - times[i]) / (stretch[i + 1] - stretch[i])
    assert len(crossings) >= 3
    measured_c = 2 * length / (2 * np.diff(crossings).mean())
    assert measured_c == pytest.approx(np.sqrt(E / rho), rel=0.05)


def test_uniaxial_stress_lateral_strain_ratio_is_poisson_ratio(device):
    """A block on a frictionless floor under its weight is in uniaxial stress: ε_lat = −ν ε_axial,
    and its mean axial strain is −ρ g h / (2E)."""
    nu, E, rho, w, h = 0.3, 1e5, 1000.0, 0.05, 0.1
    scene = make_scene(domain={"size_m": [0.2, 0.2, 0.25], "grid": 25}, ground={"friction": 0.0}, damping=100.0)
    p = Particles.lattice((-w / 2, -w / 2, 0), (w / 2, w / 2, h), scene.dx / 2, E=E, nu=nu, density=rho,
                          material_id=JELLY)
    sim = MPMSolver(p, scene, device)
    for _ in range(15):
        sim.step_frame(0.02)
    X = p.x.astype(np.float64)
    u = sim.positions().astype(np.float64) - X
    fit = np.linalg.lstsq(np.c_[X - X.mean(0), np.ones(len(X))], u, rcond=None)[0]
    strain = fit[:3].T  # mean displacement gradient
    lateral = 0.5 * (strain[0, 0] + strain[1, 1])
    assert -lateral / strain[2, 2] == pytest.approx(nu, rel=0.05)
    assert strain[2, 2] == pytest.approx(-rho * G * h / (2 * E), rel=0.05)


def test_elastic_ball_bounce_keeps_most_energy(device):
    scene = make_scene(domain={"size_m": [0.4, 0.4, 0.6], "grid": 30}, ground={"friction": 0.0})
    r, zc = 0.1, 0.35
    p = Particles.lattice((-r, -r, zc - r), (r, r, zc + r), scene.dx / 2,
                          inside=lambda x: np.linalg.norm(x - [0, 0, zc], axis=1) < r,
                          E=3e4, nu=0.4, density=100.0, material_id=JELLY)
    m = p.mass.astype(np.float64)

    def energy(sim: MPMSolver) -> float:  # kinetic + potential above the resting height (J)
        x, v = sim.positions().astype(np.float64), sim.velocities().astype(np.float64)
        return float((m * (0.5 * (v ** 2).sum(1) + G * (x[:, 2] - r))).sum())

    sim = MPMSolver(p, scene, device)
    e0 = energy(sim)
    after, lowest = [], zc
    for _ in range(50):
        sim.step_frame(0.01)
        lowest = min(lowest, float(sim.positions()[:, 2].mean()))
        if sim.velocities()[:, 2].mean() > 0.3:  # rising again after the contact
            after.append(energy(sim))
    assert lowest < r + 0.01  # it did reach the ground
    assert after, "the ball never bounced"
    assert 0.8 * e0 <= max(after) <= 1.01 * e0


# ---------------------------------------------------------------------------------------- plasticity
def test_metal_keeps_permanent_set_jelly_recovers_stationary_never_moves(device):
    """Columns squeezed by a temporary downward load: von Mises metal (and jelly given a yield
    stress) stay shorter after unloading, plain jelly returns to its elastic height; stationary
    and fixed particles in the air do not move at all."""
    scene = make_scene(domain={"size_m": [0.3, 0.12, 0.16], "grid": 30}, ground={"friction": 0.5}, damping=30.0,
                       wind=[{"acceleration": [0, 0, -20.0], "start_s": 0.0, "end_s": 0.12}])
    w, h, E, rho, dx = 0.04, 0.08, 1e5, 1000.0, scene.dx
    columns = [Particles.lattice((xc - w / 2, -w / 2, 0), (xc + w / 2, w / 2, h), dx / 2, E=E, nu=0.3,
                                 density=rho, material_id=mat, yield_stress=ys)
               for xc, mat, ys in ((-0.08, METAL, 1000.0), (0.0, JELLY, np.inf), (0.08, JELLY, 1000.0))]
    stationary = Particles.lattice((-0.02, 0.035, 0.1), (0.02, 0.05, 0.12), dx / 2, E=E, nu=0.3, density=rho,
                                   material_id=STATIONARY)
    held = Particles.lattice((0.06, 0.035, 0.1), (0.1, 0.05, 0.12), dx / 2, E=E, nu=0.3, density=rho,
                             material_id=JELLY, fixed=True)
    p = join(*columns, stationary, held)
    bounds = np.cumsum([0] + [len(c) for c in columns])
    sim = MPMSolver(p, scene, device)
    for _ in range(15):
        sim.step_frame(0.02)
    x = sim.positions()

    def height_change(k: int) -> float:
        z0, z = p.x[bounds[k]:bounds[k + 1], 2], x[bounds[k]:bounds[k + 1], 2]
        top, bottom = z0 > z0.max() - 1e-6, z0 < z0.min() + 1e-6
        return float((z[top].mean() - z[bottom].mean()) / (z0.max() - z0.min()) - 1.0)

    elastic = -rho * G * h / (2 * E)  # strain under its own weight after unloading
    metal, jelly, yielding_jelly = (height_change(k) for k in range(3))
    assert abs(jelly - elastic) < 0.004
    assert metal < elastic - 0.05
    assert yielding_jelly == pytest.approx(metal, abs=0.01)
    assert np.array_equal(x[bounds[3]:], p.x[bounds[3]:])  # stationary and fixed: bit-identical
    assert np.array_equal(sim.velocities()[bounds[3]:], np.zeros_like(p.x[bounds[3]:]))


# ---------------------------------------------------------------------------------------- forces
def free_block_sim(device: str, E: float = 1e5, **scene_keys: object) -> tuple[MPMSolver, Particles]:
    keys = {"domain": {"size_m": 1.0, "grid": 20, "origin": [-0.5, -0.5, -0.5]}, "ground": {"enabled": False},
            "gravity": [0, 0, 0], **scene_keys}
    scene = make_scene(**keys)
    p = small_block(scene, lo=(-0.1, -0.1, -0.1), hi=(0.1, 0.1, 0.1), E=E)
    return MPMSolver(p, scene, device), p


def test_viscous_damping_and_quadratic_air_drag_follow_their_laws(device):
    sim, p = free_block_sim(device, damping=3.0)
    sim.set_velocities(np.tile([0.5, 0, 0], (len(p), 1)))
    for _ in range(5):
        sim.step_frame(0.02)
    assert sim.velocities()[:, 0].mean() == pytest.approx(0.5 * np.exp(-3.0 * 0.1), rel=0.01)

    sim, p = free_block_sim(device, air_drag=4.0)
    sim.set_velocities(np.tile([0.5, 0, 0], (len(p), 1)))
    for _ in range(5):
        sim.step_frame(0.02)
    assert sim.velocities()[:, 0].mean() == pytest.approx(0.5 / (1 + 4.0 * 0.5 * 0.1), rel=0.01)


def test_wind_window_region_and_impulse(device):
    wind = {"acceleration": [2.0, 0, 0], "start_s": 0.04, "end_s": 0.1}
    impulse = {"time_s": 0.05, "velocity_change": [0, 0.3, 0], "region": {"min": [-1, -1, 0.0], "max": [1, 1, 1]}}
    sim, p = free_block_sim(device, wind=[wind], impulses=[impulse])
    for _ in range(8):
        sim.step_frame(0.02)
    v = sim.velocities()
    assert v[:, 0].mean() == pytest.approx(2.0 * 0.06, rel=0.02)  # a · (end − start)
    upper = p.x[:, 2] >= 0.0
    assert v[upper, 1].mean() > 0.1 and abs(v[~upper, 1].mean()) < v[upper, 1].mean()
    # total y-momentum given = Δv × mass of the particles inside the region when it fired
    momentum = (p.mass[:, None] * v).sum(0)
    assert momentum[1] == pytest.approx(0.3 * p.mass[upper].sum(), rel=0.01)

    gusty = dict(wind, start_s=0.0, end_s=None, gust_amplitude=1.0, gust_frequency_hz=5.0)
    sim, p = free_block_sim(device, wind=[gusty])
    for _ in range(5):
        sim.step_frame(0.02)
    T, f = 0.1, 5.0  # ∫ a (1 + sin 2πft) dt = a (T + (1 − cos 2πfT) / 2πf)
    expected = 2.0 * (T + (1 - np.cos(2 * np.pi * f * T)) / (2 * np.pi * f))
    assert sim.velocities()[:, 0].mean() == pytest.approx(expected, rel=0.02)

    outside = dict(wind, start_s=0.0, region={"min": [0.3, 0.3, 0.3], "max": [0.4, 0.4, 0.4]})
    sim, p = free_block_sim(device, wind=[outside])
    sim.step_frame(0.05)
    assert np.abs(sim.velocities()).max() < 1e-4


def test_ground_coulomb_friction_stops_a_sliding_block(device):
    """A block sliding at v0 decelerates at μg and stops after v0² / (2μg)."""
    mu, v0 = 0.4, 1.0
    scene = make_scene(domain={"size_m": [0.8, 0.2, 0.2], "grid": 40, "origin": [-0.2, -0.1, -0.06]},
                       ground={"friction": mu})
    p = small_block(scene, lo=(-0.04, -0.02, 0.0), hi=(0.04, 0.02, 0.04), E=1e5, v=[v0, 0, 0])
    sim = MPMSolver(p, scene, device)
    for _ in range(20):
        sim.step_frame(0.02)
    travel = sim.positions()[:, 0].mean() - p.x[:, 0].mean()
    assert np.abs(sim.velocities()).max() < 0.02
    assert travel == pytest.approx(v0 ** 2 / (2 * mu * G), rel=0.1)


# ---------------------------------------------------------------------------------------- covariance, guard
def test_covariance_under_homogeneous_F_is_exactly_F_sigma_FT(device):
    F = np.array([[2.0, 1.0, 0.0], [0.0, 1.0, 0.5], [0.0, 0.0, 3.0]])
    sigma = np.array([[4.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 1.0]])
    out = advect_covariances(np.stack([sigma, np.eye(3)]), np.stack([F, F]))
    assert np.array_equal(out[0], (F @ sigma @ F.T).astype(np.float32))  # small integers: exact
    assert np.array_equal(out[1], (F @ F.T).astype(np.float32))

    # through the solver: a uniform velocity gradient stretches a very soft free body (its
    # elastic waves are too slow to matter), and the covariances follow the solver's own F
    sim, p = free_block_sim(device, E=1.0)
    L = np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    sim.set_velocities(p.x @ L.T)
    sim.step_frame(0.01)
    F_sim = sim.deformation_gradients()
    cov = advect_covariances(np.tile(sigma, (len(p), 1, 1)), F_sim)
    assert np.allclose(cov, F_sim @ sigma @ np.transpose(F_sim, (0, 2, 1)), rtol=1e-5, atol=1e-6)
    centre = np.linalg.norm(p.x, axis=1) < 0.05
    assert F_sim[centre, 0, 0].mean() == pytest.approx(1.0 + 0.5 * 0.01, rel=2e-3)


def test_explosion_guard_names_frame_and_material(device):
    scene = make_scene(domain={"size_m": 0.6, "grid": 20}, solver={"max_substeps_per_frame": 1})
    p = small_block(scene, lo=(-0.05, -0.05, 0.05), hi=(0.05, 0.05, 0.15), material_id=METAL, E=1e5,
                    v=[0, 0, 200.0])
    sim = MPMSolver(p, scene, device)
    with pytest.raises(ComputationError, match=r"diverged at frame 1 \(t=0\.01 s\): material 'metal'"):
        sim.step_frame(0.01)


def test_particles_outside_the_domain_are_an_input_error(device):
    scene = make_scene(domain={"size_m": 0.5, "grid": 16})
    p = small_block(scene, lo=(0.2, 0.2, 0.1), hi=(0.3, 0.3, 0.2))
    with pytest.raises(InputError, match="outside the simulation domain"):
        MPMSolver(p, scene, device)


def test_too_stiff_material_is_softened_to_fit_the_substep_cap(device):
    scene = make_scene(domain={"size_m": 0.4, "grid": 20}, solver={"max_substeps_per_frame": 50, "stiff_parts": "soften"})
    lo, hi = (-0.04, -0.04, 0.02), (0.04, 0.04, 0.1)
    first = small_block(scene, lo=lo, hi=hi, material_id=METAL, E=7e10, density=2700.0, yield_stress=1e8)
    can = join(first, small_block(scene, lo=(0.1, 0.1, 0.02), hi=(0.14, 0.14, 0.06), material_id=METAL,
                                  E=7e10, density=2700.0))
    given = np.arange(len(can)) < len(first)  # the first block has its own yield stress
    sim = MPMSolver(can, scene, device)
    assert sim.substeps_for(1 / 30) == 50
    assert sim.stiffness_scale < 1e-3 and sim.dt * 50 >= 1 / 30
    ys = sim.yield_stresses()
    assert np.all(ys[given] == np.float32(1e8))  # a yield stress from the file is kept
    # a default yield (metal_yield_strain · E) keeps its yield strain when E is softened
    assert ys[~given] == pytest.approx(1e-3 * 7e10 * sim.stiffness_scale, rel=1e-3)
    for _ in range(6):  # falls and lands without diverging, shape kept
        sim.step_frame(1 / 30)
    z = sim.positions()[given, 2]
    assert z.min() > -0.5 * scene.dx and np.ptp(z) == pytest.approx(np.ptp(can.x[given, 2]), abs=2e-3)


def test_each_plastic_material_behaves_like_itself(device):
    """Same block, same drop: fluid spreads flat, sand slumps part-way, snow compacts (Jp < 1) and
    keeps its shape, jelly keeps its shape."""
    scene = make_scene(domain={"size_m": 0.4, "grid": 20}, ground={"friction": 0.5})
    results = {}
    for mat, name in ((4, "fluid"), (SAND, "sand"), (5, "snow"), (JELLY, "jelly")):
        p = small_block(scene, lo=(-0.04, -0.04, 0.0), hi=(0.04, 0.04, 0.12), material_id=mat, E=1e5,
                        nu=0.3, density=1000.0, v=[0, 0, -1.0])
        sim = MPMSolver(p, scene, device)
        for _ in range(12):
            sim.step_frame(1 / 30)
        results[name] = (np.ptp(sim.positions()[:, 2]) / np.ptp(p.x[:, 2]), sim.plastic_volume_ratio())
    print({k: (v[0], v[1].min()) for k, v in results.items()})
    assert results["fluid"][0] < 0.2 and results["fluid"][0] < 0.8 * results["sand"][0]
    assert 0.2 < results["sand"][0] < 0.6
    assert results["snow"][0] > 0.85 and results["snow"][1].min() < 0.95
    assert 0.95 < results["jelly"][0] < 1.05 and np.all(results["jelly"][1] == 1.0)


def test_sand_column_collapse_follows_the_runout_law(device):
    """Quarter of an axisymmetric column (a = h0/r0 = 0.5) between two slip walls (its symmetry
    planes) on a rough floor: normalised runout (r∞ − r0)/r0 within 20 % of 1.24·a (Lube et al.
    2004). benchmarks/bench_sand_collapse.py covers a = 0.5 … 3 at the same resolution."""
    r0, aspect, cells = 0.05, 0.5, 12
    dx = r0 / cells
    reach = 2.6 * r0
    scene = make_scene(domain={"size_m": [reach, reach, aspect * r0 + 8 * dx], "grid": int(round(reach / dx)),
                               "origin": [-3 * dx, -3 * dx, -3 * dx]},
                       ground={"friction": 0.5}, walls="slip")
    column = Particles.lattice((0, 0, 0), (r0, r0, aspect * r0), dx / 2,
                               inside=lambda x: np.hypot(x[:, 0], x[:, 1]) < r0,
                               E=2e5, nu=0.3, density=2000.0, material_id=SAND)
    sim = MPMSolver(column, scene, device)
    for _ in range(20):
        sim.step_frame(0.02)
        if sim.time_s > 0.2 and np.abs(sim.velocities()).max() < 0.005:
            break
    assert np.abs(sim.velocities()).max() < 0.005  # came to rest
    x = sim.positions()
    runout = (np.percentile(np.hypot(x[:, 0], x[:, 1]), 99.9) - r0) / r0
    assert runout == pytest.approx(1.24 * aspect, rel=0.2)
