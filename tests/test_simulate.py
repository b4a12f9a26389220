"""`pixie simulate` and pixie_gs.sim.run/frames/fill: real splat files, real Warp MPM on the CPU,
real rerun recordings. Known answers: placement on the ground, free fall ½gt² in the input's
coordinates, Σ' = F Σ Fᵀ in the written frames, byte-identical untouched properties."""
from __future__ import annotations

import json

import numpy as np
import pytest
from plyfile import PlyData

from pixie_gs import viz
from pixie_gs.cli.main import main
from pixie_gs.sim.fill import fill_interior
from pixie_gs.sim.frames import FrameWriter
from pixie_gs.sim.run import build_particles, placement_transform, simulate, up_rotation
from pixie_gs.sim.scene import Scene
from pixie_gs.splat import SplatCloud, read_splat, rgb_to_sh_dc

G = 9.81
CHANGED_BY_SIM = {"x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"}


def annotated_cloud(n: int = 240, seed: int = 0, materials: bool = True) -> SplatCloud:
    """A small box-shaped splat (input units, y up) with SH degree 1, normals and unknown extras."""
    rng = np.random.default_rng(seed)
    means = rng.uniform([-1.0, 0.0, -0.5], [1.0, 1.5, 0.5], (n, 3)).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)  # not normalised on purpose
    cloud = SplatCloud.from_arrays(means, log_scales=rng.uniform(-4, -2.5, (n, 3)), rotations=quats,
                                   opacity_logits=rng.normal(size=n), sh_dc=rgb_to_sh_dc(rng.random((n, 3))),
                                   sh_rest=rng.normal(size=(n, 9)) * 0.1)
    cloud.set("nx", rng.normal(size=n))
    cloud.set("feature_7", rng.normal(size=n))
    cloud.set("segment", rng.integers(0, 200, n), np.uint8)
    if materials:
        cloud.set_materials(np.zeros(n), rng.uniform(2e4, 4e4, n), rng.uniform(0.3, 0.35, n),
                            rng.uniform(100, 150, n))
    return cloud


def scene_dict(**overrides) -> dict:
    d = {"up": "y", "object": {"size_m": 0.3, "position": [0.0, 0.0, 0.0]},
         "domain": {"size_m": 1.0, "grid": 16}, "gravity": [0.0, 0.0, -G]}
    d.update(overrides)
    return d


def write_inputs(tmp_path, cloud: SplatCloud, scene: dict):
    ply, sc = tmp_path / "in.ply", tmp_path / "scene.json"
    cloud.write(ply)
    sc.write_text(json.dumps(scene))
    return ply, sc


def vertex_table(path) -> np.ndarray:
    return PlyData.read(str(path))["vertex"].data


# ---------------------------------------------------------------------------------- CLI
def test_cli_frames_tracks_and_recording(tmp_path, capsys):
    cloud = annotated_cloud()
    ply, sc = write_inputs(tmp_path, cloud, scene_dict(object={"size_m": 0.3, "position": [0, 0, 0.2]}))
    out, rrd = tmp_path / "frames", tmp_path / "run.rrd"
    before = ply.read_bytes()
    rc = main(["simulate", str(ply), "--out", str(out), "--scene", str(sc), "--frames", "4", "--fps", "20",
               "--device", "cpu", "--rrd", str(rrd), "--quiet"])
    assert rc == 0
    assert ply.read_bytes() == before  # input untouched
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"frame_{i:05d}.ply" for i in range(4)] + ["preview.png", "tracks.npz"]

    tracks = np.load(out / "tracks.npz")
    assert tracks["t"].shape == (4,) and tracks["x"].shape == (4, len(cloud), 3)
    np.testing.assert_allclose(tracks["t"], np.arange(4) / 20.0)
    np.testing.assert_array_equal(tracks["x"][0], cloud.means)  # frame 0 is the input, exactly

    src = vertex_table(ply)
    for i in range(4):
        table = vertex_table(out / f"frame_{i:05d}.ply")
        assert table.dtype == src.dtype  # every property, same order and types (uint8 extra included)
        for name in src.dtype.names:
            if name not in CHANGED_BY_SIM:
                assert table[name].tobytes() == src[name].tobytes(), name
        frame = read_splat(out / f"frame_{i:05d}.ply")
        np.testing.assert_array_equal(frame.means, tracks["x"][i])
    assert vertex_table(out / "frame_00000.ply").tobytes() == src.tobytes()  # frame 0 = input bytes
    # dropped from 0.2 m above the ground: the object has fallen (−y in the input's y-up frame)
    assert tracks["x"][-1][:, 1].mean() < tracks["x"][0][:, 1].mean() - 0.05

    entities = viz.read_recording_entities(rrd)
    assert {"/splat/rgb", "/splat/material", "/splat/log_E"} <= set(entities)
    rows = viz.read_recording_positions(rrd, "splat/rgb")
    assert [t for t, _ in rows] == pytest.approx(tracks["t"])
    tf = placement_transform(cloud.means, Scene.from_dict(scene_dict(object={"size_m": 0.3, "position": [0, 0, 0.2]})))
    np.testing.assert_allclose(rows[-1][1], tf.to_world(tracks["x"][-1]), atol=1e-5)  # world metres


def test_cli_refuses_old_frames_without_force(tmp_path, capsys):
    ply, sc = write_inputs(tmp_path, annotated_cloud(60), scene_dict())
    out = tmp_path / "o"
    args = ["simulate", str(ply), "--out", str(out), "--scene", str(sc), "--frames", "3", "--device", "cpu", "-q"]
    assert main(args) == 0
    assert main(args[:-1] + ["--frames", "2", "-q"]) == 1
    assert "--force" in capsys.readouterr().err
    assert main(args[:-1] + ["--frames", "2", "--force", "-q"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["frame_00000.ply", "frame_00001.ply", "preview.png",
                                                     "tracks.npz"]


def test_cli_missing_materials_one_line_error(tmp_path, capsys):
    ply, sc = write_inputs(tmp_path, annotated_cloud(50, materials=False), scene_dict())
    out, rrd = tmp_path / "never", tmp_path / "never.rrd"
    rc = main(["simulate", str(ply), "--out", str(out), "--scene", str(sc), "--device", "cpu",
               "--rrd", str(rrd), "-q"])
    err = capsys.readouterr().err.strip()
    assert rc == 1
    assert len(err.splitlines()) == 1 and str(ply) in err and "pixie annotate" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply", "scene.json"]  # nothing written


def test_cli_diverging_run_leaves_nothing_behind(tmp_path, capsys):
    """A kick far beyond what one substep per frame can carry: exit 3, no frames, no recording."""
    scene = scene_dict(impulses=[{"time_s": 0.0, "velocity_change": [300.0, 0.0, 0.0]}],
                       solver={"max_substeps_per_frame": 1})
    ply, sc = write_inputs(tmp_path, annotated_cloud(60), scene)
    rc = main(["simulate", str(ply), "--out", str(tmp_path / "o"), "--scene", str(sc), "--frames", "4",
               "--device", "cpu", "--rrd", str(tmp_path / "r.rrd"), "-q"])
    err = capsys.readouterr().err.strip()
    assert rc == 3 and "diverged" in err and len(err.splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply", "scene.json"]


# ---------------------------------------------------------------------------------- placement
@pytest.mark.parametrize("up", ["z", "y", "-y", "x"])
def test_placement_rests_on_the_ground(up):
    cloud = annotated_cloud(200, seed=3)
    scene = Scene.from_dict(scene_dict(up=up, object={"size_m": 0.4, "position": [0.1, -0.2, 0.0]}))
    particles, tf = build_particles(cloud, scene)
    lo, hi = particles.x.min(axis=0), particles.x.max(axis=0)
    assert lo[2] == pytest.approx(scene.ground.height_m, abs=1e-6)  # bottom on the ground
    np.testing.assert_allclose((lo[:2] + hi[:2]) / 2, [0.1, -0.2], atol=1e-6)  # bottom centre at position
    assert (hi - lo).max() == pytest.approx(0.4, rel=1e-6)  # longest side = object.size_m
    axis = "xyz".index(up[-1])
    in_extent = np.ptp(cloud.means[:, axis])
    assert hi[2] - lo[2] == pytest.approx(in_extent * tf.scale, rel=1e-5)  # the 'up' axis is now height
    np.testing.assert_allclose(tf.to_input(particles.x), cloud.means, atol=1e-5)
    # volumes: each occupied grid cell's volume is shared by its particles
    cells = np.floor((particles.x - scene.domain_origin()) / scene.dx).astype(int)
    assert particles.volume.sum() == pytest.approx(len(np.unique(cells, axis=0)) * scene.dx ** 3, rel=1e-5)


def test_part_overrides_and_fixed_parts():
    cloud = annotated_cloud(120, seed=4)
    part = np.arange(120) % 3
    cloud.set("part_id", part, np.int32)
    scene = Scene.from_dict(scene_dict(part_overrides={"1": {"E_scale": 2.0, "density_scale": 0.5,
                                                             "yield_stress_pa": 1e3}},
                                       fixed=[{"part_ids": [2]}]))
    p, _ = build_particles(cloud, scene)
    E, rho = cloud.get("E"), cloud.get("density")
    np.testing.assert_allclose(p.E[part == 1], 2 * E[part == 1], rtol=1e-6)
    np.testing.assert_allclose(p.density[part == 1], 0.5 * rho[part == 1], rtol=1e-6)
    np.testing.assert_array_equal(p.E[part != 1], E[part != 1])
    assert (p.yield_stress[part == 1] == 1e3).all() and np.isinf(p.yield_stress[part != 1]).all()
    np.testing.assert_array_equal(p.fixed, part == 2)


def test_up_rotations_are_proper():
    for up in ["x", "y", "z", "-x", "-y", "-z"]:
        R = up_rotation(up)
        axis = np.zeros(3)
        axis["xyz".index(up[-1])] = -1.0 if up.startswith("-") else 1.0
        np.testing.assert_allclose(R @ axis, [0, 0, 1], atol=1e-12)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)


# ---------------------------------------------------------------------------------- physics through the API
def test_free_fall_in_input_coordinates_up_y():
    """No ground: every Gaussian moves by ½gt² along the input's −y, in input units (1/scale)."""
    cloud = annotated_cloud(150, seed=1)
    # stiff enough that the CFL substep (≈0.5 ms) makes the time-discretisation error ≪ 1 %
    cloud.set("E", np.full(len(cloud), 3e6))
    # the object (0..0.3 m) hangs near the top of a 5 m box, so it falls freely for the whole run
    scene = Scene.from_dict(scene_dict(domain={"size_m": 5.0, "grid": 20, "origin": [-2.5, -2.5, -4.25]},
                                       ground={"enabled": False}))
    fps, frames = 8.0, 5
    traj = simulate(cloud, scene, frames, fps, device="cpu")
    scale = traj.transform.scale
    disp = traj.x - traj.x[0]  # (T,N,3) input units
    expected = 0.5 * G * traj.t ** 2 / scale
    for i in range(1, frames):
        np.testing.assert_allclose(disp[i][:, 1], -expected[i], rtol=0.01)  # ½gt² within 1 %
        np.testing.assert_allclose(disp[i][:, [0, 2]], 0.0, atol=1e-4 * expected[i])  # straight down
        assert np.ptp(disp[i][:, 1]) < 1e-3 * expected[i]  # rigid: all Gaussians alike


def test_frames_hold_advected_covariances(tmp_path):
    """Frame files carry Σ' = F Σ Fᵀ of the simulated F (an elastic block squashed on landing)."""
    cloud = annotated_cloud(200, seed=2)
    scene = Scene.from_dict(scene_dict(object={"size_m": 0.3, "position": [0, 0, 0.15]}))
    writer = FrameWriter(tmp_path / "f", cloud)
    traj = simulate(cloud, scene, 5, 15.0, device="cpu", on_frame=writer.write, keep_deformation=True)
    writer.finish(traj.t, traj.x)
    cov0 = cloud.covariances()
    moved = 0
    for i in range(5):
        F = traj.F[i].astype(np.float64)
        expected = F @ cov0 @ F.transpose(0, 2, 1)
        got = read_splat(tmp_path / "f" / f"frame_{i:05d}.ply").covariances()
        scale = np.linalg.norm(expected, axis=(1, 2))[:, None, None]
        np.testing.assert_allclose(got / scale, expected / scale, atol=2e-5)
        moved = max(moved, float(np.abs(F - np.eye(3)).max()))
    assert moved > 1e-3  # the block really deformed, so the check above is not trivial
    # landing squashes along world z, which is the input's y axis (up = y)
    strain = np.abs(np.diagonal(traj.F[-1], axis1=1, axis2=2) - 1.0).mean(axis=0)
    assert strain.argmax() == 1


def test_world_transform_maps_deformation_consistently():
    """Σ'_input mapped to the world equals F_world Σ_world F_worldᵀ (for every `up`)."""
    rng = np.random.default_rng(7)
    cloud = annotated_cloud(30, seed=7)
    F_world = np.eye(3) + 0.3 * rng.normal(size=(30, 3, 3))
    for up in ["y", "-x", "z", "-z"]:
        tf = placement_transform(cloud.means, Scene.from_dict(scene_dict(up=up)))
        F_in = tf.deformation_to_input(F_world)
        cov_in = cloud.covariances()
        lhs = tf.covariance_to_world(F_in @ cov_in @ F_in.transpose(0, 2, 1))
        cov_w = tf.covariance_to_world(cov_in)
        np.testing.assert_allclose(lhs, F_world @ cov_w @ F_world.transpose(0, 2, 1), rtol=1e-9, atol=1e-15)
        dx_w = rng.normal(size=(30, 3))
        np.testing.assert_allclose(tf.to_input(tf.to_world(cloud.means) + dx_w),
                                   cloud.means + tf.displacement_to_input(dx_w), atol=1e-5)


# ---------------------------------------------------------------------------------- interior filling
def test_fill_interior_of_a_sphere_shell():
    rng = np.random.default_rng(5)
    d = rng.normal(size=(6000, 3))
    shell = 0.2 * d / np.linalg.norm(d, axis=1, keepdims=True) + 0.5  # radius 0.2 m, centre (0.5,0.5,0.5)
    dx = 0.025
    filling = fill_interior(shell, np.zeros(3), dx, particles_per_cell=8)
    r = np.linalg.norm(filling.x - 0.5, axis=1)
    assert len(filling) > 0 and r.max() < 0.2  # only inside
    # the enclosed cells fill the ball up to about one cell under the skin
    inner_cells = len(filling) / 8
    assert inner_cells * dx ** 3 == pytest.approx(4 / 3 * np.pi * (0.2 - dx) ** 3, rel=0.25)
    # each takes its nearest Gaussian's index
    nearest = np.linalg.norm(shell[filling.source_index] - filling.x, axis=1)
    brute = np.min(np.linalg.norm(shell[None, :200] - filling.x[:50, None], axis=2), axis=1)
    assert (nearest[:50] <= brute + 1e-9).all()


def test_build_particles_with_fill_takes_nearest_material():
    rng = np.random.default_rng(6)
    d = rng.normal(size=(4000, 3))
    means = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)  # unit sphere shell
    cloud = SplatCloud.from_arrays(means)
    mid = np.where(means[:, 0] > 0, 1, 0)
    cloud.set_materials(mid, np.where(mid == 1, 1e6, 1e4), np.full(4000, 0.3), np.where(mid == 1, 2000, 100))
    scene = Scene.from_dict({"object": {"size_m": 0.5}, "domain": {"size_m": 1.0, "grid": 32}})
    p, tf = build_particles(cloud, scene, fill=True)
    extra = slice(len(cloud), None)
    assert len(p) > len(cloud) + 100
    centre_x = tf.to_world(np.zeros((1, 3)))[0, 0]
    side = p.x[extra, 0] > centre_x + scene.dx  # clearly on the +x side
    assert (p.material_id[extra][side] == 1).all() and (p.E[extra][side] == 1e6).all()
    far = p.x[extra, 0] < centre_x - scene.dx
    assert (p.material_id[extra][far] == 0).all()


@pytest.mark.parametrize("prepared", [False, True])
def test_cli_per_cell_carries_the_rest_in_free_fall(tmp_path, capsys, prepared):
    """--per-cell 2: fewer Gaussians simulated (said on the terminal), frames still hold every
    Gaussian in file order, and the carried ones fall with the simulated ones by ½gt² (no ground)."""
    cloud = annotated_cloud(900, seed=4)
    cloud.set("E", np.full(len(cloud), 3e6))  # stiff: falls as a rigid body
    scene = scene_dict(domain={"size_m": 5.0, "grid": 40, "origin": [-2.5, -2.5, -4.25]}, ground={"enabled": False})
    ply, sc = write_inputs(tmp_path, cloud, scene)
    out, fps, frames = tmp_path / "frames", 8.0, 4
    rc = main(["simulate", str(ply), "--out", str(out), "--scene", str(sc), "--frames", str(frames), "--fps",
               str(fps), "--device", "cpu", "--per-cell", "2"] + ([] if prepared else ["--no-prepare"]))
    assert rc == 0
    err = capsys.readouterr().err
    simulated = int(err.split("Gaussians simulated")[0].split("(")[-1].split(" of ")[0])
    assert simulated < 0.7 * len(cloud)  # 12.5 cm cells: ≈ 4 Gaussians per occupied cell before
    assert f" of {len(cloud)} Gaussians simulated" in err

    tracks = np.load(out / "tracks.npz")
    assert tracks["x"].shape == (frames, len(cloud), 3)
    for i in range(frames):
        frame = read_splat(out / f"frame_{i:05d}.ply")
        assert len(frame) == len(cloud)
        np.testing.assert_array_equal(frame.means, tracks["x"][i])
        np.testing.assert_array_equal(frame.get("segment"), cloud.get("segment"))  # file order kept
    # the object's longest side (x, 2 input units) becomes 0.3 m: analytic scale, same for every path
    scale = 0.3 / np.ptp(cloud.means, axis=0).max()
    disp = tracks["x"] - cloud.means
    for i in range(1, frames):
        expected = 0.5 * G * (i / fps) ** 2 / scale
        np.testing.assert_allclose(disp[i][:, 1], -expected, rtol=0.02)  # every Gaussian, carried or not
        np.testing.assert_allclose(disp[i][:, [0, 2]], 0.0, atol=0.01 * expected)
