"""The training-only part head: its targets name each voxel's (category, part) of the class table."""
from __future__ import annotations

import torch

from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.generate import object_seed
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.model.batch import build_batch
from pixie_gs.model.checkpoint import FeatureSpec
from pixie_gs.model.data import DeviceStore, record_from_cloud
from pixie_gs.model.part_labels import IGNORE, MAX_PARTS, part_label_names
from pixie_gs.model.predict import grid_channel_names
from pixie_gs.model.unet import MaterialUNet, ModelConfig, masked_loss


def test_max_parts_covers_the_class_table():
    assert max(len(spec.parts) for spec in load_class_table().values()) == MAX_PARTS


def test_voxel_part_targets_are_the_objects_own_parts():
    table = load_class_table()
    names = part_label_names()
    cloud, _ = build_object(table["tree"], object_seed(3, "test", 0), 4000)
    store = DeviceStore([record_from_cloud(cloud, [], "t", "tree")], "cpu")
    batch = build_batch(store, [0], FeatureSpec(resolution=32), part_labels=names)
    occupied = batch.target_part[batch.occupied]
    present = {names[i] for i in occupied.unique().tolist() if i != IGNORE}
    own = {f"tree/{p.name}" for p in table["tree"].parts if (cloud.get("part_id") == p.part_id).any()}
    assert present == own  # every voxel names a part the tree has, and each part shows up
    assert (batch.target_part[~batch.occupied] == IGNORE).all()


def test_part_term_joins_the_loss_only_with_a_weight():
    names = part_label_names()
    net = MaterialUNet(ModelConfig(input_channels=grid_channel_names(()), base_channels=8, part_labels=names))
    x = torch.randn(1, len(grid_channel_names(())), 16, 16, 16)
    logits, phys, parts = net(x, with_parts=True)
    occ = torch.ones(1, 16, 16, 16, dtype=torch.bool)
    target = torch.zeros(1, 16, 16, 16, dtype=torch.long)
    tp = torch.zeros(1, 3, 16, 16, 16)
    base, p0 = masked_loss(logits, phys, target, tp, occ)
    both, p1 = masked_loss(logits, phys, target, tp, occ, 1.0, parts, target, 0.5)
    assert p0["ce_part"] == 0.0 and p1["ce_part"] > 1.0  # ~ln 35 from an untrained head
    assert abs(float(both - base) - 0.5 * p1["ce_part"]) < 1e-4
