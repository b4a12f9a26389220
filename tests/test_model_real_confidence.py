"""Confidence of the shipped checkpoint separates held-out generated objects of its classes — capture-like
and clean converter output, the two kinds of input its statistics describe — from out-of-vocabulary
splats (issue 12). The out-of-vocabulary set is made here from analytic shapes no
recipe builds: an isotropic noise cloud, a rainbow torus, a 2 m cyan sheet, a lattice of 36 magenta
rods, a cube of large random-colour blobs, and a nearly transparent black icosphere."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from pixie_gs.convert import mesh_to_splat
from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.generate import object_seed
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.model.checkpoint import load_checkpoint
from pixie_gs.model.metrics import separation_auroc
from pixie_gs.model.predict import predict_materials
from pixie_gs.model.stats import PAPER_CLASSES
from pixie_gs.splat import SplatCloud

N = 4000


def _out_of_vocabulary(rng: np.random.Generator) -> list[SplatCloud]:
    noise = SplatCloud.from_arrays(rng.normal(size=(N, 3)), log_scales=np.full((N, 3), np.log(0.05)),
                                   rgb=rng.uniform(0, 1, (N, 3)))
    torus = mesh_to_splat(trimesh.creation.torus(0.5, 0.1), N, rng, color_noise=0.3)
    sheet = mesh_to_splat(trimesh.creation.box((2, 2, 0.01)), N, rng, rgb=np.array([0.2, 0.9, 0.9], np.float32))
    rods = trimesh.util.concatenate([trimesh.creation.box((0.02, 0.02, 1), trimesh.transformations.translation_matrix(
        [x, y, 0])) for x in np.linspace(-0.5, 0.5, 6) for y in np.linspace(-0.5, 0.5, 6)])
    lattice = mesh_to_splat(rods, N, rng, rgb=np.array([0.9, 0.1, 0.9], np.float32))
    blobs = SplatCloud.from_arrays(rng.uniform(-1, 1, (N // 2, 3)), log_scales=np.full((N // 2, 3), np.log(0.2)),
                                   rgb=rng.uniform(0, 1, (N // 2, 3)))
    ghost = mesh_to_splat(trimesh.creation.icosphere(1, 1.0), N, rng, rgb=np.array([0.1, 0.1, 0.1], np.float32),
                          opacity=0.05)
    return [noise, torus, sheet, lattice, blobs, ghost]


def test_confidence_separates_training_classes_from_out_of_vocabulary():
    loaded = load_checkpoint(None, "cpu")
    assert "feature_stats" in loaded.meta  # the shipped checkpoint carries its training statistics
    table = load_class_table()

    def mean_confidence(cloud: SplatCloud) -> float:
        g = predict_materials(loaded, cloud, "cpu")
        return float(g.confidence[g.occupancy].mean())

    inside = [mean_confidence(build_object(table[name], object_seed(99, "test", i), N, realistic=i % 2 == 0)[0])
              for i, name in enumerate(table)]  # every class; capture-like and clean in turn
    outside = [mean_confidence(c) for c in _out_of_vocabulary(np.random.default_rng(1))]
    auroc = separation_auroc(inside, outside)
    print(f"AUROC {auroc:.3f}")
    assert auroc >= 0.8, (auroc, inside, outside)
    assert np.median(inside) > 0.8 and min(outside) < 0.1


@pytest.mark.parametrize("name,index", [("tree", 0), ("soda_cans", 6), ("sand", 8)])
def test_classes_robust_to_capture_artefacts(name, index):
    """Issue 12 robustness: ‖f_rest‖ = 0.5 (degree 1), capture-like opacities (logit N(−0.94, 2.6), the
    real captures' median 0.28), 5 % floaters in the box and a 30° tilt each keep ≥ 95 % of the clean
    prediction's per-Gaussian material classes."""
    import math

    from pixie_gs.splat import quat_to_rotmat, rotmat_to_quat
    from pixie_gs.transfer import nearest_voxel_values

    loaded = load_checkpoint(None, "cpu")
    rng = np.random.default_rng(index)

    def classes(cloud: SplatCloud) -> np.ndarray:
        g = predict_materials(loaded, cloud, "cpu")
        return nearest_voxel_values(g.grid.extra["means_unit"], g.classes, g.physical, g.occupancy)[0]

    clean, _ = build_object(load_class_table()[name], object_seed(77, "test", index), 6000)
    n = len(clean)
    base = classes(clean)
    sh = clean.copy()
    r = rng.normal(size=(n, 9))
    sh.sh_rest = (0.5 * r / np.linalg.norm(r, axis=1, keepdims=True)).astype(np.float32)
    faint = clean.copy()
    faint.opacity_logits = rng.normal(-0.94, 2.6, n).astype(np.float32)
    k = n // 20
    extra = clean.subset(rng.integers(0, n, k))
    extra.means = rng.uniform(clean.means.min(0), clean.means.max(0), (k, 3)).astype(np.float32)
    floaters = SplatCloud.concatenate([clean, extra])
    a, phi = math.radians(30), rng.uniform(0, 2 * math.pi)
    axis = np.array([math.cos(phi), math.sin(phi), 0.0])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K
    tilted = clean.copy()
    tilted.means = (clean.means @ R.T).astype(np.float32)
    tilted.rotations = rotmat_to_quat(R[None] @ quat_to_rotmat(clean.quats)).astype(np.float32)
    for what, cloud in (("f_rest", sh), ("opacity", faint), ("floaters", floaters), ("tilt", tilted)):
        agree = float((classes(cloud)[:n] == base).mean())
        assert agree >= 0.95, (name, what, agree)


def test_a_dense_converted_mesh_is_not_called_a_guess():
    """A can converted from a mesh at 100k Gaussians (what `pixie convert` gives a user's mesh) is read as
    metal and stays in distribution: its grid is denser and its opacity constant, unlike most training
    objects, but the checkpoint describes clean objects apart (model/stats.py --by-look). Pooled
    statistics alone put this can at 0.51 and the real set's converted Duck and WaterBottle under 0.5."""
    loaded = load_checkpoint(None, "cpu")
    can = mesh_to_splat(trimesh.creation.cylinder(0.033, 0.12, 48), 100_000, np.random.default_rng(0),
                        rgb=np.array([0.8, 0.1, 0.1], np.float32))
    g = predict_materials(loaded, can, "cpu")
    classes = np.bincount(g.classes[g.occupancy], minlength=7)
    assert classes.argmax() == 1, classes  # metal
    assert g.in_distribution > 0.9, g.in_distribution


def test_separation_auroc_known_answers():
    # pairs (3,1) (3,2) (2,1) win, (2,2) ties: (1 + 1 + 1 + 0.5) / 4
    assert separation_auroc([3.0, 2.0], [1.0, 2.0]) == 0.875
    assert separation_auroc([5.0, 6.0], [1.0, 2.0]) == 1.0 and separation_auroc([1.0], [5.0, 6.0]) == 0.0
    assert separation_auroc([float("nan")], [1.0]) == 0.0  # a NaN never counts as separating
