"""Interior leftovers (pixie_gs/dataset/leftovers.py): large opaque Gaussians inside closed pieces, as
trained captures hold; checked against the geometry of the meshes they are drawn in, not against the
generator's own numbers."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from pixie_gs.convert import mesh_to_splat
from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.dataset.realism import capture_like
from pixie_gs.dataset.leftovers import LEFTOVER_SIGMA_REL, interior_leftovers, leftover_rng
from pixie_gs.field import feature_grid

TABLE = load_class_table()


def _sphere(radius_m: float = 0.1):
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=radius_m)
    cloud = mesh_to_splat(mesh, 3000, np.random.default_rng(0), rgb=np.array([0.8, 0.3, 0.1], np.float32))
    return mesh, cloud


def test_leftovers_lie_inside_closed_pieces_large_flat_and_opaque():
    mesh, cloud = _sphere(0.1)
    inner = interior_leftovers([mesh], [cloud], np.random.default_rng(1))[0]
    assert inner is not None and 0.05 * len(cloud) - 1 <= len(inner) <= 0.3 * len(cloud) + 1
    assert np.linalg.norm(inner.means, axis=1).max() < 0.1  # inside the sphere (its radius, m)
    s = np.sort(inner.scales, axis=1)
    diagonal = np.linalg.norm(mesh.bounds[1] - mesh.bounds[0])
    rel = s[:, 2] / diagonal
    assert LEFTOVER_SIGMA_REL[0] * 0.99 <= rel.min() and rel.max() <= LEFTOVER_SIGMA_REL[1] * 1.01
    assert np.all(s[:, 0] < 0.11 * s[:, 2])  # flat discs: σ_min ≤ 0.1 σ_max
    assert np.median(inner.opacities) > 0.85
    assert np.allclose(inner.rgb(), np.median(cloud.rgb(), axis=0), atol=0.02)  # the surface's colour


def test_open_pieces_get_none():
    box = trimesh.creation.box((0.2, 0.2, 0.2))
    open_box = trimesh.Trimesh(box.vertices, box.faces[2:], process=False)  # one face missing: not closed
    cloud = mesh_to_splat(open_box, 2000, np.random.default_rng(0))
    assert interior_leftovers([open_box], [cloud], np.random.default_rng(1)) == [None]


def test_leftovers_fill_the_grid_inside_a_shell():
    """A hollow sphere's grid is empty at its centre; with leftovers it is occupied there, as the real
    donut capture's tube is (what the model must learn to see past)."""
    mesh, cloud = _sphere(0.1)
    from pixie_gs.splat import SplatCloud

    filled = SplatCloud.concatenate([cloud, interior_leftovers([mesh], [cloud], np.random.default_rng(2))[0]])
    centre = []
    for c in (cloud, filled):
        g = feature_grid(c, 32)
        centre.append(float(g.occupancy[12:20, 12:20, 12:20].mean()))
    assert centre[0] == 0.0 and centre[1] > 0.5, centre


def test_build_object_records_leftovers():
    spec = TABLE["bread"]
    plain, rec0 = build_object(spec, 5, 3000, realistic=True, leftover_share=0.0)
    with_left, rec1 = build_object(spec, 5, 3000, realistic=True, leftover_share=1.0)
    assert rec0["realism"]["leftovers"] == 0 and rec1["realism"]["leftovers"] > 0
    assert len(with_left) > len(plain)
    assert set(np.unique(with_left.get("part_id"))) == set(np.unique(plain.get("part_id")))


def test_capture_like_keeps_the_opacity_it_is_told_to():
    """Held Gaussians keep their logits through capture_like (drops and floaters included); the rest get
    the capture-like spread."""
    _, cloud = _sphere(0.1)
    cloud.opacity_logits = np.full(len(cloud), 3.0, np.float32)
    cloud.set("tag", np.arange(len(cloud)), np.int64)
    held = np.zeros(len(cloud), bool)
    held[::3] = True
    for seed in range(6):
        out, _, rec = capture_like(cloud.copy(), np.zeros(len(cloud), np.int32), np.random.default_rng(seed),
                                   keep_opacity=held)
        tag = out.get("tag")[: len(out) - rec.floaters]
        kept = out.opacity_logits[: len(tag)][held[tag]]
        assert rec.leftovers == int(held[tag].sum()) > 0
        assert np.all(kept == 3.0)
        if rec.opacity_mode == "capture":
            assert np.ptp(out.opacity_logits[: len(tag)][~held[tag]]) > 1.0


def test_leftover_stream_is_separate_from_the_object_stream():
    """The leftover RNG depends on the object seed only, so objects that draw none are unchanged."""
    a, b = leftover_rng(7).random(4), leftover_rng(7).random(4)
    assert np.array_equal(a, b) and not np.array_equal(a, np.random.default_rng(7).random(4))


def test_generate_leftover_share_decides_which_objects_hold_them(tmp_path):
    """`generate_split(leftover_share=…)`: 0 gives no object leftovers, 1 gives every capture-like object
    with a closed piece some; clean objects never get any; a share outside 0–1 is refused."""
    import json

    from pixie_gs.dataset.generate import generate_split
    from pixie_gs.errors import InputError

    counts = {}
    for share in (0.0, 1.0):
        split = generate_split(tmp_path / f"s{share}", 4, classes=["bread", "stones"], seed=3,
                               n_gaussians=1500, leftover_share=share)
        records = [json.loads(p.read_text()) for p in sorted(split.glob("0*.json"))]
        counts[share] = [r["realism"]["leftovers"] for r in records]
        assert json.loads((split / "index.json").read_text())["leftover_share"] == share
    assert counts[0.0] == [0, 0, 0, 0] and all(n > 0 for n in counts[1.0]), counts
    clean = generate_split(tmp_path / "clean", 2, classes=["bread"], seed=3, n_gaussians=1500, realistic=False,
                           leftover_share=1.0)
    assert json.loads((clean / "index.json").read_text())["leftover_share"] == 0.0
    with pytest.raises(InputError, match="--leftovers"):
        generate_split(tmp_path / "bad", 1, leftover_share=1.5)
