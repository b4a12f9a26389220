"""Scene preparation: --up parsing, up/ground on a synthetic tilted floor, floaters, roles, sidecar."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pixie_gs.cli.main import build_parser, main
from pixie_gs.errors import InputError
from pixie_gs.field import up_rotation
from pixie_gs.prepare import (ROLE_FLOATER, ROLE_GROUND, ROLE_OBJECT, fix_negative_up, parse_up, prepare_cloud,
                              rotation_to_z)
from pixie_gs.prepare.updir import angle_deg
from pixie_gs.splat import SplatCloud, read_splat, rotmat_to_quat, write_splat


def flat_gaussians(points: np.ndarray, normals: np.ndarray, size: float, rgb) -> SplatCloud:
    """Surface Gaussians (discs of std `size`, 10× thinner along `normals`) at `points`."""
    z = np.array([0.0, 0.0, 1.0])
    R = np.stack([rotation_to_z(n).T for n in normals])  # maps z to the normal
    assert np.allclose(np.einsum("nij,j->ni", R, z), normals, atol=1e-6)
    scales = np.log(np.tile([size, size, size / 10], (len(points), 1)))
    return SplatCloud.from_arrays(points, log_scales=scales, rotations=rotmat_to_quat(R),
                                  rgb=np.broadcast_to(np.asarray(rgb, np.float32), points.shape))


def floor_and_box(tilt: np.ndarray, n_floor: int = 12000, n_box: int = 6000, seed: int = 0):
    """A 3 m × 3 m floor at height 0 with a 0.5 m cube standing on it, then turned by `tilt`."""
    rng = np.random.default_rng(seed)
    floor = np.column_stack([rng.uniform(-1.5, 1.5, (n_floor, 2)), np.zeros(n_floor)])
    fn = np.tile([0.0, 0.0, 1.0], (n_floor, 1))
    face = rng.integers(0, 5, n_box)  # the 5 visible faces (not the bottom)
    uv = rng.uniform(-0.25, 0.25, (n_box, 2))
    pts = np.empty((n_box, 3))
    nrm = np.zeros((n_box, 3))
    for k, (axis, sign) in enumerate([(0, 1), (0, -1), (1, 1), (1, -1), (2, 1)]):
        m = face == k
        other = [a for a in range(3) if a != axis]
        pts[m, axis] = sign * 0.25
        pts[m, other[0]], pts[m, other[1]] = uv[m, 0], uv[m, 1]
        nrm[m, axis] = sign
    pts[:, 2] += 0.25
    # one Gaussian size everywhere: no "seen better from above" evidence, the floor alone decides
    cloud = SplatCloud.concatenate([flat_gaussians(floor, fn, 0.008, (0.5, 0.5, 0.5)),
                                    flat_gaussians(pts, nrm, 0.008, (0.8, 0.2, 0.2))])
    R = np.asarray(tilt)
    cloud.means = (cloud.means.astype(np.float64) @ R.T).astype(np.float32)
    cloud.set_covariances(R @ cloud.covariances() @ R.T)
    return cloud, n_floor


# ------------------------------------------------------------------------------------------ --up
@pytest.mark.parametrize("text, expected", [("z", (0, 0, 1)), ("-y", (0, -1, 0)), ("+x", (1, 0, 0)),
                                            ("0,-1,0", (0, -1, 0)), ("0 0 2", (0, 0, 1))])
def test_parse_up_axes_and_vectors(text, expected):
    assert np.allclose(parse_up(text), expected)


def test_parse_up_vector_is_normalised_and_auto_is_none():
    v = parse_up("0,-1,-0.6")
    assert np.isclose(np.linalg.norm(v), 1.0) and np.allclose(v / v[1], [0, 1, 0.6])
    assert parse_up("auto") is None and parse_up(None) is None


@pytest.mark.parametrize("bad", ["w", "1,2", "0,0,0", "a,b,c", "--y", "nan,0,1"])
def test_parse_up_rejects_nonsense(bad):
    with pytest.raises(InputError):
        parse_up(bad)


@pytest.mark.parametrize("command", ["annotate", "prepare"])
def test_up_minus_y_parses_with_a_space(command):
    argv = fix_negative_up([command, "in.ply", "out.ply", "--up", "-y"])
    args = build_parser().parse_args(argv)
    assert args.up == "-y"
    args = build_parser().parse_args(fix_negative_up([command, "in.ply", "out.ply", "--up", "-0.1,1,0"]))
    assert np.allclose(parse_up(args.up), np.array([-0.1, 1, 0]) / np.linalg.norm([-0.1, 1, 0]))


def test_simulate_takes_up_minus_y():
    args = build_parser().parse_args(fix_negative_up(["simulate", "in.ply", "--out", "d", "--up", "-y"]))
    assert args.up == "-y" and not args.no_prepare


def test_rotation_to_z_equals_the_axis_tables_and_turns_any_vector_up():
    for axis in ("z", "-z", "y", "-y", "x", "-x"):
        assert np.allclose(rotation_to_z(axis), up_rotation(axis))
    for v in Rotation.random(20, random_state=1).apply([0, 0, 1]):
        R = rotation_to_z(v)
        assert np.allclose(R @ v, [0, 0, 1]) and np.isclose(np.linalg.det(R), 1.0)


# ------------------------------------------------------------------------------------ up, ground
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tilted_floor_gives_up_ground_height_and_object(seed):
    tilt = Rotation.from_rotvec(np.radians(35) * np.array([np.cos(seed), np.sin(seed), 0.0])).as_matrix()
    cloud, n_floor = floor_and_box(tilt, seed=seed)
    out, scene = prepare_cloud(cloud)
    truth = tilt @ [0, 0, 1]
    assert angle_deg(scene.up, truth) < 3.0
    assert scene.up_method.startswith("ground-plane") and scene.ground_height is not None
    assert abs(scene.ground_height) < 0.01  # the floor passes through the origin (tilted about it)
    role = out.get("role")
    assert np.mean(role[:n_floor] == ROLE_GROUND) > 0.95
    assert np.mean(role[n_floor:] == ROLE_OBJECT) > 0.9
    assert len(scene.objects) == 1
    lo, hi = np.asarray(scene.objects[0].box_up)
    assert np.allclose(hi - lo, [0.5, 0.5, 0.5], atol=0.05)  # the cube, measured in the up frame


# -------------------------------------------------------------------------------------- floaters
@pytest.fixture(scope="module")
def can_and_floaters():
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.labels import load_class_table

    cloud, _ = build_object(load_class_table()["metal_crates"], 4242, 4000)
    for name in ("material_id", "E", "nu", "density", "part_id"):
        cloud.extras.pop(name, None)
    cloud.property_order = [p for p in cloud.property_order if p in cloud.extras or p[:2] in ("x", "y", "z")
                            or not p.startswith(("material", "E", "nu", "dens", "part"))]
    rng = np.random.default_rng(3)
    lo, hi = cloud.bounds()
    centre, size = (lo + hi) / 2, float((hi - lo).max())
    k = int(0.05 * len(cloud))
    far = centre + rng.uniform(-2.0, 2.0, (k, 3)) * size
    far = far[np.abs(far - centre).max(axis=1) > 0.75 * size]
    floaters = SplatCloud.from_arrays(far, log_scales=np.full((len(far), 3), np.log(0.01 * size)),
                                      opacity_logits=rng.normal(0, 2, len(far)), rgb=rng.random((len(far), 3)))
    return cloud, SplatCloud.concatenate([cloud, floaters])


def test_far_floaters_are_marked_and_do_not_move_the_object_box(can_and_floaters):
    clean, noisy = can_and_floaters
    _, s_clean = prepare_cloud(clean, up="z")
    out, s_noisy = prepare_cloud(noisy, up="z")
    role = out.get("role")
    n = len(clean)
    assert np.mean(role[n:] == ROLE_FLOATER) > 0.95
    assert np.mean(role[:n] == ROLE_OBJECT) > 0.99
    a, b = np.asarray(s_clean.objects[0].fit_box_up), np.asarray(s_noisy.objects[0].fit_box_up)
    size = (a[1] - a[0]).max()
    assert np.abs(a - b).max() <= 0.05 * size


def test_floaters_do_not_change_the_predicted_classes(can_and_floaters):
    from pixie_gs.annotate import annotate_cloud

    clean, noisy = can_and_floaters
    pc, sc = prepare_cloud(clean, up="z")
    pn, sn = prepare_cloud(noisy, up="z")
    a = annotate_cloud(pc, device="cpu", prepared=sc).get("material_id")
    b = annotate_cloud(pn, device="cpu", prepared=sn).get("material_id")[:len(clean)]
    assert np.mean(a == b) >= 0.95
    plain = annotate_cloud(noisy, device="cpu", up="z").get("material_id")[:len(clean)]
    assert np.mean(plain == a) < np.mean(a == b) or np.mean(plain == a) >= 0.95  # preparation never hurts


# --------------------------------------------------------------------------- generated objects
@pytest.mark.parametrize("index", range(4))
def test_up_of_generated_objects_with_a_base_under_random_rotations(index):
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.labels import load_class_table

    name = ["sand", "snow_mud", "grass", "sand"][index]
    cloud, _ = build_object(load_class_table()[name], 100 + index, 6000)
    R = Rotation.random(random_state=index).as_matrix()
    cloud.means = (cloud.means.astype(np.float64) @ R.T).astype(np.float32)
    cloud.set_covariances(R @ cloud.covariances() @ R.T)
    _, scene = prepare_cloud(cloud)
    assert angle_deg(scene.up, R @ [0, 0, 1]) < 10.0


# ------------------------------------------------------------------------------- CLI and sidecar
def test_prepare_cli_writes_roles_and_sidecar(tmp_path, capsys):
    tilt = Rotation.from_euler("xy", [25, -15], degrees=True).as_matrix()
    cloud, n_floor = floor_and_box(tilt, 6000, 3000)
    src, out = tmp_path / "capture.ply", tmp_path / "prepared.ply"
    write_splat(cloud, src)
    before = src.read_bytes()
    assert main(["prepare", str(src), str(out), "-q"]) == 0
    assert src.read_bytes() == before
    summary = [line for line in capsys.readouterr().out.splitlines() if line.startswith("prepared")]
    assert len(summary) == 1 and "ground at" in summary[0]
    res = read_splat(out)
    assert res.get("role").dtype == np.uint8 and res.get("object_id").dtype == np.int32
    assert len(res) == len(cloud) and np.array_equal(res.means, cloud.means)  # nothing moved or dropped
    assert set(np.unique(res.get("object_id")[res.get("role") != ROLE_OBJECT])) == {-1}
    side = json.loads((tmp_path / "prepared.prepare.json").read_text())
    assert angle_deg(side["up"], tilt @ [0, 0, 1]) < 3.0
    assert side["counts"]["ground"] > 0.9 * n_floor and side["role_codes"]["2"] == "ground"
    for key in ("up_method", "up_confidence", "angle_from_axis_deg", "nearest_axis", "ground_height", "objects"):
        assert key in side
    assert 20 < side["angle_from_axis_deg"] < 35


def test_annotate_prepares_a_tilted_capture_with_no_flag(tmp_path):
    tilt = Rotation.from_euler("x", 30, degrees=True).as_matrix()
    cloud, n_floor = floor_and_box(tilt, 6000, 3000)
    src, out = tmp_path / "capture.ply", tmp_path / "annotated.ply"
    write_splat(cloud, src)
    assert main(["annotate", str(src), str(out), "--device", "cpu", "-q"]) == 0
    side = json.loads((tmp_path / "annotated.prepare.json").read_text())
    assert angle_deg(side["up"], tilt @ [0, 0, 1]) < 3.0
    res = read_splat(out)
    mid = res.get("material_id")
    assert np.all(mid[:n_floor][np.abs(np.asarray(res.means[:n_floor]) @ (tilt @ [0, 0, 1])) < 0.01] == 6)
    assert [p for p in res.property_order if p in ("role", "object_id")] == []
    # the prepared path keeps the model's confidence and records the up it used, so a later
    # `pixie simulate` of this file turns it the same way (declared, not estimated again)
    assert res.has("confidence") and np.isfinite(res.get("confidence")).all()
    declared = [c for c in res.comments if c.startswith("pixie up ")]
    assert len(declared) == 1
    assert angle_deg([float(w) for w in declared[0].split()[2:]], side["up"]) < 1e-3
    _, again = prepare_cloud(res)
    assert again.up_method == "declared by the file" and angle_deg(again.up_vector, side["up"]) < 1e-3


def test_bad_crop_and_up_fail_cleanly(tmp_path, capsys):
    cloud, _ = floor_and_box(np.eye(3), 2000, 1000)
    src = tmp_path / "c.ply"
    write_splat(cloud, src)
    assert main(["prepare", str(src), str(tmp_path / "o.ply"), "--crop", "box:1,2", "-q"]) == 1
    assert "--crop" in capsys.readouterr().err
    assert not (tmp_path / "o.ply").exists()
    with pytest.raises(SystemExit):
        main(["prepare", str(src), str(tmp_path / "o.ply"), "--up", "sideways"])


# ------------------------------------------------------------------- declared up, flat-based sign
def test_gltf_declares_y_up_and_prepare_honours_it(tmp_path):
    """glTF's spec defines +Y as up: `pixie convert` records it in the PLY header, the INRIA reader
    and writer keep the comment, and prepare takes it with confidence 1 (even for a shape whose
    own evidence would say otherwise: a box lying along z)."""
    import trimesh

    mesh = trimesh.creation.box(extents=[0.2, 0.3, 1.0])
    glb = tmp_path / "thing.glb"
    mesh.export(str(glb))
    ply = tmp_path / "thing.ply"
    assert main(["convert", str(glb), str(ply), "--count", "3000", "-q"]) == 0
    cloud = read_splat(ply)
    assert "pixie up 0 1 0" in cloud.comments
    again = tmp_path / "again.ply"
    write_splat(cloud, again)
    assert read_splat(again).comments == cloud.comments
    _, scene = prepare_cloud(cloud)
    assert np.allclose(scene.up, [0, 1, 0]) and scene.up_confidence == 1.0
    assert scene.up_method == "declared by the file" and scene.up_source == "file"
    _, given = prepare_cloud(cloud, up="z")  # the user's --up still wins
    assert np.allclose(given.up, [0, 0, 1]) and given.up_source == "given"


@pytest.mark.parametrize("height, radius", [(0.4, 0.5), (1.5, 0.3)])
def test_sign_of_up_on_a_flat_based_cone(height, radius):
    """A cone stands on its flat base, apex up (analytic truth: its axis), under random turns;
    one Gaussian size everywhere, so only the shape (base plane, heavy end) can give the sign."""
    import trimesh

    from pixie_gs.convert import mesh_to_splat

    mesh = trimesh.creation.cone(radius=radius, height=height, sections=48)
    cloud = mesh_to_splat(mesh, 6000, np.random.default_rng(0))
    for k in range(3):
        R = Rotation.random(random_state=10 + k).as_matrix()
        turned = cloud.copy()
        turned.means = (cloud.means.astype(np.float64) @ R.T).astype(np.float32)
        turned.set_covariances(R @ cloud.covariances() @ R.T)
        _, scene = prepare_cloud(turned)
        assert angle_deg(scene.up, R @ [0, 0, 1]) < 10.0, scene.up_method


# ------------------------------------------------------------------------------- objects vs background
def box_surface(lo, hi, count: int, rng, faces=(0, 1, 2, 3, 4, 5)) -> tuple[np.ndarray, np.ndarray]:
    """`count` points (and outward normals) uniform over the chosen faces (0/1: −x/+x, 2/3: ±y, 4/5: ±z)
    of the box (lo, hi), each face getting points in proportion to its area."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    size = hi - lo
    areas = np.array([np.prod(np.delete(size, f // 2)) for f in faces])
    face = np.asarray(faces)[rng.choice(len(faces), count, p=areas / areas.sum())]
    pts = lo + rng.uniform(0, 1, (count, 3)) * size
    nrm = np.zeros((count, 3))
    for f in faces:
        m = face == f
        axis, side = f // 2, f % 2
        pts[m, axis] = hi[axis] if side else lo[axis]
        nrm[m, axis] = 1.0 if side else -1.0
    return pts, nrm


def ball_surface(centre, radius: float, count: int, rng) -> tuple[np.ndarray, np.ndarray]:
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.asarray(centre) + radius * d, d


def scene_of(parts: list[tuple[np.ndarray, np.ndarray]], size: float = 0.006) -> tuple[SplatCloud, list[slice]]:
    """One cloud of surface Gaussians from (points, normals) parts, with each part's slice."""
    clouds, slices, start = [], [], 0
    for pts, nrm in parts:
        clouds.append(flat_gaussians(pts, nrm, size, (0.6, 0.5, 0.4)))
        slices.append(slice(start, start + len(pts)))
        start += len(pts)
    return SplatCloud.concatenate(clouds), slices


def test_a_large_thing_beside_a_small_one_is_an_object():
    """A ball 0.25 m across beside a 0.8 m crate, 25 cm apart with no floor, the ball with a few more
    Gaussians (a capture spends them on detail, not area: the ball is the main object), are two objects,
    though the crate is 3.2× the ball's size (before: the crate was background, written as stationary)."""
    rng = np.random.default_rng(3)
    ball = ball_surface([0.0, 0.0, 0.125], 0.125, 14000, rng)
    crate = box_surface([0.375, -0.4, 0.0], [1.175, 0.4, 0.8], 13000, rng, faces=(0, 1, 2, 3, 5))
    cloud, (ball_at, crate_at) = scene_of([ball, crate])
    prepared, scene = prepare_cloud(cloud, up="z")
    role, object_id = prepared.get("role"), prepared.get("object_id")
    assert (role[ball_at] == ROLE_OBJECT).mean() > 0.95 and (role[crate_at] == ROLE_OBJECT).mean() > 0.95
    # the ball one object; the crate, sparse next to it, may come in more than one piece but never with it
    assert np.unique(object_id[ball_at]).size == 1 and object_id[ball_at][0] not in set(object_id[crate_at])
    assert len(scene.objects) >= 2


@pytest.mark.parametrize("name, background", [("crate", False), ("wall", True), ("room", True)])
def test_pick_objects_keeps_big_compact_neighbours_and_drops_walls_and_rooms(name, background):
    """Two clusters, the ball the main one (heavier, at the scene centre): the second, 4× or more its size,
    is an object when it is a compact thing beside it, background when it is a sheet or a shell over it."""
    from pixie_gs.prepare.objects import pick_objects

    rng = np.random.default_rng(4)
    ball, _ = ball_surface([0.0, 0.0, 0.1], 0.1, 3000, rng)
    other, _ = {"crate": box_surface([0.35, -0.4, 0.0], [1.15, 0.4, 0.8], 2000, rng),
                "wall": box_surface([-1.0, 0.4, 0.0], [1.0, 0.41, 1.5], 2000, rng, faces=(2,)),
                "room": box_surface([-1.5, -1.5, 0.0], [1.5, 1.5, 2.2], 2000, rng, faces=(0, 1, 2, 3, 5))}[name]
    points = np.vstack([ball, other])
    labels = np.repeat([0, 1], [len(ball), len(other)])
    out = pick_objects(points, np.ones(len(points)), labels, centre=np.array([0.0, 0.0, 0.1]))
    assert (out[:len(ball)] == 0).all()
    assert (out[len(ball):] == -1).all() if background else (out[len(ball):] == 1).all()


@pytest.mark.parametrize("box, background", [
    (([0, 0, 0], [1.0, 1.0, 1.0]), False),   # a crate 4× the main object's size, beside it
    (([0, 0, 0], [0.5, 0.5, 0.5]), False),   # only 2× its size: an object whatever its shape
    (([0, 0, 0], [2.0, 0.02, 1.5]), True),   # a wall (sheet)
    (([-0.1, 0, 0], [1.0, 1.0, 0.1]), True),  # a board under-and-beside it, thinner than 0.15 of its length: a sheet
    (([-1, -1, 0], [1, 1, 1.5]), True),      # a room shell whose footprint holds the main object's centre
])
def test_looks_like_background_by_size_sheet_and_surround(box, background):
    from pixie_gs.prepare.objects import looks_like_background

    main_lo, main_hi = np.array([-0.25, -0.1, 0.0]), np.array([-0.05, 0.1, 0.2])  # 0.25 m, outside x ≥ 0
    lo, hi = (np.asarray(v, float) for v in box)
    assert looks_like_background(lo, hi, main_lo, main_hi) is background
