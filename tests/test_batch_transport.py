"""What a batch sends between its processes: a prepared asset pickles without the model cloud's copy of
the input and comes back equal; a part prediction pickles without its feature grid; the split
predict_grids (model process) + assemble (pool process) gives the single-file `predict` result."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from pixie_gs.annotate import PartPrediction
from pixie_gs.batch.steps import AnnotateOptions, PreparedAsset, assemble, predict, predict_grids
from pixie_gs.prepare import prepare_cloud


@pytest.fixture(scope="module")
def asset() -> PreparedAsset:
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.labels import load_class_table

    cloud, _ = build_object(load_class_table()["soda_cans"], 7, 3000)
    model_cloud, scene = prepare_cloud(cloud)
    return PreparedAsset(cloud, model_cloud, scene)


def clouds_equal(a, b) -> bool:
    fields = ("means", "log_scales", "rotations", "opacity_logits", "sh_dc", "sh_rest")
    return (all(np.array_equal(getattr(a, f), getattr(b, f)) for f in fields)
            and a.property_order == b.property_order and a.comments == b.comments
            and set(a.extras) == set(b.extras)
            and all(a.extras[k].dtype == b.extras[k].dtype and np.array_equal(a.extras[k], b.extras[k])
                    for k in a.extras))


def test_prepared_asset_round_trip_rebuilds_the_model_cloud(asset):
    data = pickle.dumps(asset, protocol=pickle.HIGHEST_PROTOCOL)
    back = pickle.loads(data)
    assert clouds_equal(back.cloud, asset.cloud)
    assert clouds_equal(back.model_cloud, asset.model_cloud)
    assert back.model_cloud is not back.cloud
    both = pickle.dumps((asset.cloud, asset.model_cloud), protocol=pickle.HIGHEST_PROTOCOL)
    assert len(data) < 0.6 * len(both)  # the input travels once, plus role and object_id


def test_unprepared_asset_round_trip_keeps_one_cloud(asset):
    bare = PreparedAsset(asset.cloud, asset.cloud, None)
    back = pickle.loads(pickle.dumps(bare))
    assert back.model_cloud is back.cloud and back.prepared is None
    assert clouds_equal(back.cloud, asset.cloud)


def test_split_prediction_equals_single_file_predict_and_drops_the_grid(asset):
    opts = AnnotateOptions(device="cpu")
    parts = predict_grids(asset, opts)
    assert parts and all(isinstance(p, PartPrediction) and p.mgrid is not None for p in parts)
    sent = pickle.loads(pickle.dumps(parts))
    assert all(p.mgrid is None for p in sent)
    assert np.array_equal(sent[0].means_unit, parts[0].means_unit)
    assert clouds_equal(assemble(pickle.loads(pickle.dumps(asset)), sent), predict(asset, opts))
