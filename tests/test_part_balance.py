"""Part-balanced loss weights (`pixie train --part-balance`): hand-counted weights on a two-part object."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from pixie_gs.materials import BACKGROUND, JELLY, METAL, NUM_CLASSES, normalize_physical
from pixie_gs.model.part_balance import label_parts, part_balance_weights
from pixie_gs.model.unet import masked_loss

N = 4


def _plant_and_block():
    """Object 0: a 'plant' of 60 leaf voxels (elastic, 2e4 Pa) and 4 stem voxels (elastic, 5e9 Pa); object 1:
    64 voxels of one metal block. Returns target_class, target_physical, occupied."""
    occ = torch.ones(2, N, N, N, dtype=torch.bool)
    target_class = torch.full((2, N, N, N), JELLY)
    target_class[1] = METAL
    leaf, stem, block = (torch.from_numpy(normalize_physical(np.array([e]), np.array([nu]), np.array([rho]))[0])
                         for e, nu, rho in ((2e4, 0.4, 400.0), (5e9, 0.3, 700.0), (2e11, 0.3, 7800.0)))
    target_phys = torch.empty(2, 3, N, N, N)
    target_phys[0] = leaf.view(3, 1, 1, 1)
    target_phys[0, :, 0, 0, :] = stem.view(3, 1)  # 4 stem voxels along one edge
    target_phys[1] = block.view(3, 1, 1, 1)
    return target_class, target_phys, occ


def test_alpha_one_gives_each_part_of_an_object_the_same_total_weight():
    target_class, target_phys, occ = _plant_and_block()
    w = part_balance_weights(target_class, target_phys, occ, 1.0, NUM_CLASSES)
    stem = torch.zeros_like(occ)
    stem[0, 0, 0, :] = True
    leaves = occ.clone()
    leaves[0][stem[0]] = False
    leaves[1] = False
    # 64 voxels in two parts: 32 each, so a stem voxel weighs 32 / 4 = 8 and a leaf voxel 32 / 60
    assert torch.allclose(w[stem], torch.full((4,), 8.0))
    assert torch.allclose(w[leaves], torch.full((60,), 32 / 60))
    assert torch.allclose(w[1], torch.ones(N, N, N))  # one part: the plain mean
    assert float(w.sum()) == pytest.approx(128.0)  # the occupied count: still a mean


def test_alpha_half_weighs_by_the_square_root_and_keeps_each_objects_share():
    target_class, target_phys, occ = _plant_and_block()
    w = part_balance_weights(target_class, target_phys, occ, 0.5, NUM_CLASSES)
    stem_w, leaf_w = float(w[0, 0, 0, 0]), float(w[0, 1, 1, 1])
    assert stem_w / leaf_w == pytest.approx(math.sqrt(60 / 4), rel=1e-5)
    assert float(w[0].sum()) == pytest.approx(64.0) and float(w[1].sum()) == pytest.approx(64.0)


def test_unoccupied_voxels_get_no_weight_and_no_part():
    target_class, target_phys, occ = _plant_and_block()
    occ[1, 3] = False
    target_class[1, 3] = BACKGROUND
    w = part_balance_weights(target_class, target_phys, occ, 1.0, NUM_CLASSES)
    assert float(w[1, 3].abs().sum()) == 0.0 and float(w[1].sum()) == pytest.approx(48.0)
    assert bool((label_parts(target_class, target_phys[:, 0], occ, NUM_CLASSES)[1, 3] == -1).all())


def test_labels_within_one_decade_of_e_are_one_part():
    target_class, target_phys, occ = _plant_and_block()
    near = torch.from_numpy(normalize_physical(np.array([2.5e4]), np.array([0.4]), np.array([400.0]))[0])
    target_phys[0, :, 3, 3, 3] = near  # 2.5e4 Pa beside leaves of 2e4 Pa: the same decade
    parts = label_parts(target_class, target_phys[:, 0], occ, NUM_CLASSES)
    assert len(torch.unique(parts[0])) == 2 and len(torch.unique(parts[1])) == 1


def test_zero_alpha_is_the_plain_mean_and_weights_scale_a_small_parts_error():
    target_class, target_phys, occ = _plant_and_block()
    logits = torch.zeros(2, NUM_CLASSES, N, N, N)
    logits[:, JELLY] = 4.0
    logits[1, METAL] = 4.0
    phys = target_phys.clone()
    plain, _ = masked_loss(logits, phys, target_class, target_phys, occ)
    same, _ = masked_loss(logits, phys, target_class, target_phys, occ,
                          voxel_weight=part_balance_weights(target_class, target_phys, occ, 0.0, NUM_CLASSES))
    assert float(same) == pytest.approx(float(plain), rel=1e-6)
    # an error of 1 in normalised log E on the 4 stem voxels only: plain MSE 4/128; balanced 8 × that
    phys[0, 0, 0, 0, :] += 1.0
    _, plain_parts = masked_loss(logits, phys, target_class, target_phys, occ)
    _, balanced_parts = masked_loss(logits, phys, target_class, target_phys, occ,
                                    voxel_weight=part_balance_weights(target_class, target_phys, occ, 1.0,
                                                                      NUM_CLASSES))
    assert plain_parts["mse_log_E"] == pytest.approx(4 / 128, rel=1e-5)
    assert balanced_parts["mse_log_E"] == pytest.approx(8 * 4 / 128, rel=1e-5)


@pytest.mark.parametrize("value", ["1.5", "-0.1", "nan"])
def test_train_rejects_a_part_balance_outside_zero_to_one(tmp_path, capsys, value):
    from pixie_gs.cli.main import main

    rc = main(["train", str(tmp_path), "--out", str(tmp_path / "m.pt"), "--part-balance", value, "--device", "cpu",
               "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "--part-balance must be within 0–1" in err[0], (rc, err)
    assert not (tmp_path / "m.pt").exists()


def test_training_with_part_balance_on_generated_potted_trees(tmp_path):
    """Generated potted trees (pot, trunk, foliage: parts of different E) train with α = 0.5 and the run
    records it; their voxels fall into several parts, so the weights do differ from the plain mean."""
    from pixie_gs.cli.main import main
    from pixie_gs.model.batch import build_batch
    from pixie_gs.model.checkpoint import FeatureSpec, load_checkpoint
    from pixie_gs.model.data import DeviceStore, load_split
    from pixie_gs.model.train import TrainConfig, train

    data = tmp_path / "trees"
    for split, count in (("train", 3), ("val", 1)):
        assert main(["generate", str(data), "--count", str(count), "--split", split, "--gaussians", "600",
                     "--classes", "tree", "-q"]) == 0
    records, extra = load_split(data, "train")
    batch = build_batch(DeviceStore(records, "cpu"), [0, 1, 2], FeatureSpec(resolution=16, extra_names=tuple(extra)))
    parts = label_parts(batch.target_class, batch.target_physical[:, 0], batch.occupied, NUM_CLASSES)
    assert all(len(torch.unique(parts[b][batch.occupied[b]])) >= 2 for b in range(3))
    w = part_balance_weights(batch.target_class, batch.target_physical, batch.occupied, 0.5, NUM_CLASSES)
    assert float(w[batch.occupied].std()) > 0.1
    assert float(w.sum()) == pytest.approx(float(batch.occupied.sum()), rel=1e-4)
    cfg = TrainConfig(epochs=1, batch_size=3, lr=5e-3, warmup_steps=1, part_balance=0.5,
                      model={"base_channels": 4, "multipliers": [1, 2]}, features={"resolution": 16})
    meta = train(data, tmp_path / "m.pt", cfg, "cpu")
    assert meta["train_config"]["part_balance"] == 0.5
    assert math.isfinite(meta["history"][-1]["train_loss"])
    assert load_checkpoint(tmp_path / "m.pt").meta["train_config"]["part_balance"] == 0.5
