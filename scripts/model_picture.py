"""Picture of the shipped model at work: held-out generated objects by RGB, true and predicted material.

usage: python scripts/model_picture.py docs/annotate_examples.png
Objects come from the generator's *test* split seeds (never seen in training); each row shows one
object three times: base colour, true material class, class predicted by `annotate_cloud` on CPU.
"""
from __future__ import annotations

import sys

import numpy as np

from pixie_gs.annotate import annotate_cloud
from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.generate import object_seed
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.render import contact_sheet, material_panels, save_png
from pixie_gs.splat import LABEL_ATTRIBUTES

CLASSES = ["tree", "flowers", "grass", "soda_cans", "sand", "snow_mud"]


def main(out: str) -> None:
    table = load_class_table()
    images, labels = [], []
    for i, name in enumerate(CLASSES):
        cloud, _ = build_object(table[name], object_seed(1, "test", 5000 + i), 20000)
        true_id = cloud.get_materials()[0]
        bare = cloud.copy()
        for attr in LABEL_ATTRIBUTES:
            bare.extras.pop(attr, None)
        bare.property_order = [p for p in bare.property_order if p not in LABEL_ATTRIBUTES]
        pred_id = annotate_cloud(bare, device="cpu").get_materials()[0]
        acc = float(np.mean(pred_id == true_id))
        row_images, row_labels = material_panels(cloud, true_id, pred_id, name, f"predicted ({acc:.1%} agree)")
        images += row_images
        labels += row_labels
    save_png(contact_sheet(images, labels, columns=3), out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/annotate_examples.png")
