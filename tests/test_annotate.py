"""Transfer to Gaussians and the `pixie annotate` command: properties kept, orientation, bad input."""
from __future__ import annotations

import numpy as np
import pytest

from pixie_gs.cli.main import main
from pixie_gs.errors import ComputationError
from pixie_gs.materials import BACKGROUND, JELLY, METAL, SAND, STATIONARY, normalize_physical
from pixie_gs.splat import SplatCloud, read_splat, write_splat
from pixie_gs.transfer import nearest_voxel_values, write_materials

LABELS = ("material_id", "E", "nu", "density", "part_id")


def test_transfer_takes_nearest_material_voxel_and_never_background():
    n = 8
    classes = np.full((n, n, n), BACKGROUND)
    occ = np.zeros((n, n, n), bool)
    physical = np.zeros((3, n, n, n), np.float32)
    occ[1, 1, 1], classes[1, 1, 1], physical[:, 1, 1, 1] = True, METAL, [0.5, 0.1, 0.9]
    occ[6, 6, 6], classes[6, 6, 6], physical[:, 6, 6, 6] = True, SAND, [-0.5, 0.2, 0.3]
    occ[4, 4, 4], classes[4, 4, 4] = True, BACKGROUND  # occupied but predicted background: never used
    classes[2, 2, 2] = JELLY  # a material in an EMPTY voxel: never used
    points = np.array([[0.55, 0.55, 0.55],  # inside the background voxel (4,4,4), nearer to (6,6,6)
                       [0.3, 0.3, 0.3],  # inside empty voxel (2,2,2) → nearest candidate (1,1,1)
                       [0.99, 0.0, 0.99]])
    mat, phys = nearest_voxel_values(points, classes, physical, occ)
    assert mat.tolist() == [SAND, METAL, SAND]
    assert np.allclose(phys[1], [0.5, 0.1, 0.9]) and np.allclose(phys[0], [-0.5, 0.2, 0.3])
    rng = np.random.default_rng(0)
    mat, _ = nearest_voxel_values(rng.uniform(0, 1, (500, 3)), classes, physical, occ)
    assert BACKGROUND not in mat and set(mat.tolist()) <= {SAND, METAL}


def test_transfer_without_any_material_voxel_is_a_computation_error():
    n = 4
    with pytest.raises(ComputationError, match="no occupied voxel"):
        nearest_voxel_values(np.full((2, 3), 0.5), np.full((n, n, n), BACKGROUND), np.zeros((3, n, n, n)),
                             np.ones((n, n, n), bool))


def test_write_materials_converts_to_si_units():
    cloud = SplatCloud.from_arrays(np.zeros((2, 3)))
    phys = normalize_physical(np.array([2e6, 5e10]), np.array([0.4, 0.3]), np.array([400.0, 2700.0]))
    out = write_materials(cloud, np.array([JELLY, STATIONARY]), phys)
    mid, E, nu, rho = out.get_materials()
    assert mid.tolist() == [JELLY, STATIONARY]
    assert np.allclose(E, [2e6, 5e10], rtol=1e-4) and np.allclose(nu, [0.4, 0.3], atol=1e-5)
    assert np.allclose(rho, [400, 2700], rtol=1e-4)
    assert not cloud.has_materials()  # the input cloud is untouched


@pytest.fixture(scope="module")
def can_splat(tmp_path_factory):
    """A generated soda can (z-up, labels removed) with extra properties a real file might carry."""
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.labels import load_class_table

    cloud, _ = build_object(load_class_table()["soda_cans"], 777, 3000)
    for name in LABELS:
        del cloud.extras[name]
    cloud.property_order = [p for p in cloud.property_order if p not in LABELS]
    rng = np.random.default_rng(5)
    cloud.sh_rest = rng.normal(0, 0.05, (len(cloud), 9)).astype(np.float32)
    cloud.property_order[cloud.property_order.index("opacity"):cloud.property_order.index("opacity")] = [
        f"f_rest_{i}" for i in range(9)]
    cloud.set("clip_0", rng.normal(size=len(cloud)))
    cloud.set("instance_id", rng.integers(0, 1000, len(cloud)), np.int32)
    path = tmp_path_factory.mktemp("can") / "can.ply"
    write_splat(cloud, path)
    return path


def test_annotate_cli_keeps_every_input_property(can_splat, tmp_path):
    out = tmp_path / "can_annotated.ply"
    before = can_splat.read_bytes()
    assert main(["annotate", str(can_splat), str(out), "--device", "cpu", "-q"]) == 0
    assert can_splat.read_bytes() == before  # the input is never modified
    src, dst = read_splat(can_splat), read_splat(out)
    assert dst.property_order[:len(src.property_order)] == src.property_order
    assert dst.property_order[len(src.property_order):] == ["material_id", "E", "nu", "density", "confidence"]
    for name in src.extras:
        assert np.array_equal(src.extras[name], dst.extras[name]) and src.extras[name].dtype == dst.extras[name].dtype
    for attr in ("means", "log_scales", "rotations", "opacity_logits", "sh_dc", "sh_rest"):
        assert np.array_equal(getattr(src, attr), getattr(dst, attr))
    mid, E, nu, rho = dst.get_materials()
    assert np.mean(mid == METAL) > 0.95
    # metal-stiff and aluminium-dense; this can lies on its side, where the shipped checkpoint puts E
    # ~1e10 Pa rather than the label's 6e10 (docs/model_card.md, known weaknesses)
    assert 3e9 < np.median(E) < 2e11 and 2000 < np.median(rho) < 3500


def test_annotate_honours_the_up_axis(can_splat, tmp_path):
    """The same can stored y-up, annotated with --up y, gets the same materials as the z-up file."""
    cloud = read_splat(can_splat)
    to_y_up = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], np.float64)  # z → y (inverse of up_rotation('y'))
    turned = cloud.copy()
    turned.means = (cloud.means @ to_y_up.T).astype(np.float32)
    turned.set_covariances(to_y_up @ cloud.covariances() @ to_y_up.T)
    y_in, y_out, z_out = tmp_path / "y.ply", tmp_path / "y_out.ply", tmp_path / "z_out.ply"
    write_splat(turned, y_in)
    assert main(["annotate", str(y_in), str(y_out), "--up", "y", "--device", "cpu", "-q"]) == 0
    # --up z: this can lies on its side, which its shape alone cannot tell from standing (auto reads it as standing)
    assert main(["annotate", str(can_splat), str(z_out), "--up", "z", "--device", "cpu", "-q"]) == 0
    a, b = read_splat(y_out).get_materials(), read_splat(z_out).get_materials()
    assert np.mean(a[0] == b[0]) > 0.99
    assert np.median(np.abs(np.log10(a[1]) - np.log10(b[1]))) < 0.05


def test_annotate_writes_a_rerun_recording(can_splat, tmp_path):
    from pixie_gs.viz import read_recording_entities

    rrd = tmp_path / "can.rrd"
    assert main(["annotate", str(can_splat), str(tmp_path / "o.ply"), "--rrd", str(rrd), "--device", "cpu", "-q"]) == 0
    entities = read_recording_entities(rrd)
    for view in ("splat/rgb", "splat/material", "splat/log_E"):
        assert entities.get(f"/{view}", entities.get(view, 0)) >= 1


def test_annotate_bad_input_fails_cleanly(can_splat, tmp_path, capsys):
    out = tmp_path / "never.ply"
    missing = tmp_path / "missing.ply"
    assert main(["annotate", str(missing), str(out), "-q"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "missing.ply" in err and "no such file" in err
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x00")
    assert main(["annotate", str(bad), str(out), "-q"]) == 1
    assert "bad.ply" in capsys.readouterr().err
    ckpt = tmp_path / "junk.pt"
    ckpt.write_bytes(b"junk")
    assert main(["annotate", str(can_splat), str(out), "--checkpoint", str(ckpt), "--device", "cpu", "-q"]) == 1
    assert "junk.pt" in capsys.readouterr().err
    assert main(["annotate", str(can_splat), str(can_splat), "-q"]) == 1  # would overwrite the input
    assert "refusing" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".never.ply*"))  # no partial output
