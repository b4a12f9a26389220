"""SplatCloud I/O: byte-exact round trips, material attributes, and one-line errors for bad files."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from pixie_gs.atomic import atomic_path, check_distinct_output
from pixie_gs.errors import InputError
from pixie_gs.splat import SH_C0, SplatCloud, quat_to_rotmat, read_splat, rotmat_to_quat

CORE = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(45)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def make_table(n: int = 500, seed: int = 0, rest: int = 45, drop: tuple[str, ...] = ()) -> np.ndarray:
    """A 3DGS vertex table with random values, unknown float/int extras interleaved at the end."""
    rng = np.random.default_rng(seed)
    names = [p for p in CORE if not (p.startswith("f_rest_") and int(p[7:]) >= rest) and p not in drop]
    dtype = [(p, "<f4") for p in names] + [("feature_7", "<f4"), ("instance_id", "<i4"), ("flag", "u1")]
    table = np.zeros(n, dtype=dtype)
    for p in names:
        table[p] = rng.normal(size=n).astype(np.float32)
    table["feature_7"] = rng.normal(size=n)
    table["instance_id"] = rng.integers(-1000, 1000, n)
    table["flag"] = rng.integers(0, 255, n)
    return table


def write_table(path: Path, table: np.ndarray, text: bool = False, byte_order: str = "<") -> Path:
    PlyData([PlyElement.describe(table, "vertex")], text=text, byte_order=byte_order).write(str(path))
    return path


def raw_bytes(column: np.ndarray) -> bytes:
    return np.ascontiguousarray(column).tobytes()


def test_round_trip_is_bit_exact_and_ordered(tmp_path: Path) -> None:
    table = make_table()
    src = write_table(tmp_path / "in.ply", table)
    original = src.read_bytes()
    cloud = read_splat(src)
    assert cloud.sh_degree == 3 and len(cloud) == len(table)
    cloud.write(tmp_path / "out.ply")
    back = PlyData.read(str(tmp_path / "out.ply"))["vertex"].data
    assert back.dtype.names == table.dtype.names
    for name in table.dtype.names:
        assert back.dtype[name] == table.dtype[name].newbyteorder("<")
        assert raw_bytes(back[name]) == raw_bytes(table[name]), name
    assert src.read_bytes() == original  # input untouched


@pytest.mark.parametrize("text,byte_order", [(False, ">"), (True, "=")])
def test_big_endian_and_ascii_inputs_read_identically(tmp_path: Path, text: bool, byte_order: str) -> None:
    table = make_table(rest=9)
    cloud = read_splat(write_table(tmp_path / "in.ply", table, text=text, byte_order=byte_order))
    assert cloud.sh_degree == 1
    np.testing.assert_array_equal(cloud.means[:, 0], table["x"])
    np.testing.assert_array_equal(cloud.sh_rest[:, 8], table["f_rest_8"])
    np.testing.assert_array_equal(cloud.extras["instance_id"], table["instance_id"])


def test_material_attributes_round_trip(tmp_path: Path) -> None:
    cloud = read_splat(write_table(tmp_path / "in.ply", make_table(n=64)))
    rng = np.random.default_rng(3)
    mid = rng.integers(0, 7, 64)
    E, nu, rho = rng.uniform(1e3, 1e10, 64), rng.uniform(0.2, 0.45, 64), rng.uniform(50, 7000, 64)
    cloud.set_materials(mid, E, nu, rho)
    cloud.write(tmp_path / "mat.ply")
    back = read_splat(tmp_path / "mat.ply")
    got = back.get_materials()
    assert got[0].dtype == np.int32
    np.testing.assert_array_equal(got[0], mid)
    np.testing.assert_array_equal(got[1], E.astype(np.float32))
    np.testing.assert_array_equal(got[2], nu.astype(np.float32))
    np.testing.assert_array_equal(got[3], rho.astype(np.float32))
    assert back.property_order[-4:] == ["material_id", "E", "nu", "density"]
    assert back.property_order[: len(make_table(1).dtype.names)] == list(make_table(1).dtype.names)


def test_helpers_rgb_covariance_and_unit_cube() -> None:
    rng = np.random.default_rng(1)
    cloud = SplatCloud.from_arrays(rng.uniform(-3, 7, (200, 3)), log_scales=rng.normal(-3, 0.5, (200, 3)),
                                   rotations=rng.normal(size=(200, 4)) * 5.0, rgb=rng.uniform(0.1, 0.9, (200, 3)))
    np.testing.assert_allclose(cloud.rgb(), 0.5 + SH_C0 * cloud.sh_dc, atol=1e-6)
    R = quat_to_rotmat(cloud.rotations)
    S = np.exp(cloud.log_scales.astype(np.float64))
    np.testing.assert_allclose(cloud.covariances(), R @ (S[:, :, None] ** 2 * np.eye(3)) @ R.transpose(0, 2, 1),
                               rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.abs(rotmat_to_quat(R)), np.abs(cloud.quats), atol=1e-6)
    unit, tf = cloud.normalized(margin=0.05)
    lo, hi = unit.bounds()
    assert np.isclose(np.max(hi - lo), 0.9, atol=1e-5) and (lo >= 0.05 - 1e-6).all() and (hi <= 0.95 + 1e-6).all()
    np.testing.assert_allclose(tf.to_world(unit.means), cloud.means, atol=1e-5)
    expected = cloud.covariances() * tf.scale**2
    np.testing.assert_allclose(unit.covariances(), expected, rtol=1e-4, atol=1e-5 * np.abs(expected).max())


def test_non_unit_quaternions_are_normalised_on_use(tmp_path: Path) -> None:
    table = make_table(n=10, rest=0)
    for k in ("rot_0", "rot_1", "rot_2", "rot_3"):
        table[k] *= 7.0
    cloud = read_splat(write_table(tmp_path / "q.ply", table))
    np.testing.assert_allclose(np.linalg.norm(cloud.quats, axis=1), 1.0, atol=1e-6)


# ---------------------------------------------------------------- bad inputs
def _bad_files(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    good = write_table(tmp_path / "good.ply", make_table(n=50))
    cases: dict[str, tuple[Path, str]] = {}
    p = tmp_path / "not_ply.ply"
    p.write_bytes(b"hello world, not a ply\n")
    cases["not a ply"] = (p, "not a PLY")
    p = tmp_path / "truncated.ply"
    p.write_bytes(good.read_bytes()[:-1000])
    cases["truncated"] = (p, "truncated")
    p = tmp_path / "no_vertex.ply"
    face = np.zeros(3, dtype=[("a", "f4")])
    PlyData([PlyElement.describe(face, "face")]).write(str(p))
    cases["no vertex element"] = (p, "no 'vertex' element")
    cases["missing property"] = (write_table(tmp_path / "missing.ply", make_table(n=5, drop=("scale_1",))),
                                 "missing required vertex properties: scale_1")
    cases["zero vertices"] = (write_table(tmp_path / "empty.ply", make_table(n=0)), "zero vertices")
    t = make_table(n=5)
    t["y"][3] = np.nan
    cases["nan position"] = (write_table(tmp_path / "nan.ply", t), "non-finite position")
    t = make_table(n=5)
    t["scale_2"][1] = np.inf
    cases["inf scale"] = (write_table(tmp_path / "inf.ply", t), "non-finite scale")
    t = make_table(n=5)
    for k in ("rot_0", "rot_1", "rot_2", "rot_3"):
        t[k][2] = 0.0
    cases["zero quaternion"] = (write_table(tmp_path / "zeroq.ply", t), "zero-length")
    cases["sh count"] = (write_table(tmp_path / "sh.ply", make_table(n=5, rest=10)), "f_rest properties")
    return cases


def test_each_bad_input_raises_a_message_naming_file_and_problem(tmp_path: Path) -> None:
    for label, (path, needle) in _bad_files(tmp_path).items():
        with pytest.raises(InputError) as err:
            read_splat(path)
        message = str(err.value)
        assert str(path) in message and needle in message, (label, message)
        assert "\n" not in message


def test_cli_reports_bad_inputs_in_one_line_with_nonzero_exit(tmp_path: Path) -> None:
    for label, (path, needle) in _bad_files(tmp_path).items():
        proc = subprocess.run([sys.executable, "-m", "pixie_gs", "info", str(path)], capture_output=True, text=True)
        assert proc.returncode == 1, label
        assert proc.stdout == ""
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0] and "Traceback" not in proc.stderr, (label, proc.stderr)


def test_info_prints_counts_and_materials(tmp_path: Path) -> None:
    cloud = read_splat(write_table(tmp_path / "in.ply", make_table(n=30)))
    cloud.set_materials(np.r_[np.zeros(10), np.ones(20)], np.full(30, 2e6), np.full(30, 0.3), np.full(30, 400))
    cloud.write(tmp_path / "m.ply")
    proc = subprocess.run([sys.executable, "-m", "pixie_gs", "info", str(tmp_path / "m.ply"), "--json"],
                          capture_output=True, text=True, check=True)
    import json

    info = json.loads(proc.stdout.strip().splitlines()[-1])
    assert info["count"] == 30 and info["sh_degree"] == 3
    assert info["materials"]["jelly"]["count"] == 10 and info["materials"]["metal"]["count"] == 20


def test_atomic_path_leaves_nothing_on_failure_and_keeps_old_file(tmp_path: Path) -> None:
    target = tmp_path / "out.ply"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.ply"]


def test_atomic_output_gets_the_users_usual_permissions(tmp_path: Path) -> None:
    import os

    umask = os.umask(0o022)
    try:
        with atomic_path(tmp_path / "out.ply") as tmp:
            tmp.write_text("x")
    finally:
        os.umask(umask)
    assert (tmp_path / "out.ply").stat().st_mode & 0o777 == 0o644


def test_output_equal_to_input_is_refused_without_force(tmp_path: Path) -> None:
    src = write_table(tmp_path / "in.ply", make_table(n=5))
    with pytest.raises(InputError, match="--force"):
        check_distinct_output(src, tmp_path / "." / "in.ply")
    check_distinct_output(src, src, force=True)
    check_distinct_output(src, tmp_path / "other.ply")
