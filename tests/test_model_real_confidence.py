"""Confidence of the shipped checkpoint separates held-out generated objects of its classes from
out-of-vocabulary splats (issue 12). The out-of-vocabulary set is made here from analytic shapes no
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

    inside = [mean_confidence(build_object(table[name], object_seed(99, "test", i), N)[0])
              for i, name in enumerate(PAPER_CLASSES)]
    outside = [mean_confidence(c) for c in _out_of_vocabulary(np.random.default_rng(1))]
    auroc = np.mean([(a > b) + 0.5 * (a == b) for a in inside for b in outside])
    assert auroc >= 0.8, (auroc, inside, outside)
    assert np.median(inside) > 0.8 and min(outside) < 0.1
