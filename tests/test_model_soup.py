"""Model soups (pixie_gs/model/soup.py): weights are the exact mean, metadata is kept honestly, and
checkpoints of different networks are refused."""
from __future__ import annotations

import pytest
import torch

from pixie_gs.errors import InputError
from pixie_gs.model.checkpoint import FeatureSpec, load_checkpoint, save_checkpoint
from pixie_gs.model.predict import grid_channel_names
from pixie_gs.model.soup import ingredient_validations, main, make_soup, union_ranges
from pixie_gs.model.unet import MaterialUNet, ModelConfig

NAMES = grid_channel_names(())
SPEC = FeatureSpec(resolution=16)


def _checkpoint(path, seed: int, base: int = 8, meta: dict | None = None):
    torch.manual_seed(seed)
    model = MaterialUNet(ModelConfig(input_channels=NAMES, base_channels=base, multipliers=[1, 2]))
    save_checkpoint(path, model, SPEC, meta or {})
    return model


def test_soup_weights_are_the_mean_and_the_network_runs(tmp_path):
    stats = {"channels": ["a"], "objects": 3, "mean": [0.5], "std": [0.1]}
    m1 = _checkpoint(tmp_path / "a.pt", 1, meta={"label_ranges": {"nu": [0.2, 0.4]}, "best_epoch": 3})
    m2 = _checkpoint(tmp_path / "b.pt", 2, meta={"label_ranges": {"nu": [0.25, 0.45]}, "feature_stats": stats})
    meta = make_soup([tmp_path / "a.pt", tmp_path / "b.pt"], tmp_path / "soup.pt")
    soup = load_checkpoint(tmp_path / "soup.pt")
    s1, s2 = m1.state_dict(), m2.state_dict()
    for name, value in soup.model.state_dict().items():
        assert torch.allclose(value, (s1[name] + s2[name]) / 2, atol=1e-7), name
    assert meta["label_ranges"] == {"nu": [0.2, 0.45]} and meta["feature_stats"] == stats
    assert [s["file"] for s in meta["soup_of"]] == ["a.pt", "b.pt"] and meta["soup_of"][0]["best_epoch"] == 3
    assert len(meta["soup_of"][1]["sha256"]) == 64 and soup.meta == meta
    x = torch.randn(1, len(NAMES), 16, 16, 16)
    with torch.no_grad():
        logits, phys = soup.model(x)
    assert torch.isfinite(logits).all() and torch.isfinite(phys).all()


def test_a_soup_of_soups_keeps_every_trained_ingredients_validation(tmp_path):
    val = lambda acc: {"val": {"voxel": {"accuracy": acc, "mse_avg": 0.05}}, "best_epoch": 1}  # noqa: E731
    for name, seed, acc in (("a", 1, 0.97), ("b", 2, 0.98), ("c", 3, 0.99)):
        _checkpoint(tmp_path / f"{name}.pt", seed, meta=val(acc))
    make_soup([tmp_path / "a.pt", tmp_path / "b.pt"], tmp_path / "ab.pt")
    meta = make_soup([tmp_path / "ab.pt", tmp_path / "c.pt"], tmp_path / "abc.pt")
    inner = meta["soup_of"][0]
    assert inner["file"] == "ab.pt" and inner["val_voxel"] is None  # a soup has no validation of its own …
    assert [s["file"] for s in inner["soup_of"]] == ["a.pt", "b.pt"]  # … but keeps its ingredients'
    assert [v["accuracy"] for v in ingredient_validations(meta)] == [0.97, 0.98, 0.99]
    assert ingredient_validations(load_checkpoint(tmp_path / "c.pt").meta) == [{"accuracy": 0.99, "mse_avg": 0.05}]


def test_soup_of_copies_predicts_like_the_original(tmp_path):
    model = _checkpoint(tmp_path / "a.pt", 4)
    (tmp_path / "b.pt").write_bytes((tmp_path / "a.pt").read_bytes())
    make_soup([tmp_path / "a.pt", tmp_path / "b.pt"], tmp_path / "soup.pt")
    x = torch.randn(1, len(NAMES), 16, 16, 16)
    model.eval()
    with torch.no_grad():
        assert torch.allclose(model(x)[0], load_checkpoint(tmp_path / "soup.pt").model(x)[0], atol=1e-5)


def test_soup_refuses_other_networks_and_single_inputs(tmp_path, capsys):
    _checkpoint(tmp_path / "a.pt", 1)
    _checkpoint(tmp_path / "wide.pt", 1, base=16)
    with pytest.raises(InputError, match="'config' differs"):
        make_soup([tmp_path / "a.pt", tmp_path / "wide.pt"], tmp_path / "soup.pt")
    with pytest.raises(InputError, match="at least two"):
        make_soup([tmp_path / "a.pt"], tmp_path / "soup.pt")
    with pytest.raises(InputError, match="not found"):
        make_soup([tmp_path / "a.pt", tmp_path / "missing.pt"], tmp_path / "soup.pt")
    (tmp_path / "text.pt").write_text("not a checkpoint")
    with pytest.raises(InputError, match="not a readable torch checkpoint"):
        make_soup([tmp_path / "a.pt", tmp_path / "text.pt"], tmp_path / "soup.pt")
    torch.save({"weights": torch.zeros(3)}, tmp_path / "foreign.pt")  # a torch file, not a pixie-gs checkpoint
    with pytest.raises(InputError, match="not a pixie-gs material checkpoint"):
        make_soup([tmp_path / "foreign.pt", tmp_path / "a.pt"], tmp_path / "soup.pt")
    assert not (tmp_path / "soup.pt").exists()
    _checkpoint(tmp_path / "b.pt", 2)
    main([str(tmp_path / "soup.pt"), str(tmp_path / "a.pt"), str(tmp_path / "b.pt")])
    assert "mean of 2 checkpoints" in capsys.readouterr().out


def test_union_ranges():
    assert union_ranges([{"E": [1, 3], "nu": [0.2, 0.3]}, {"E": [0.5, 2]}]) == {"E": [0.5, 3]}


def test_soup_reads_configs_with_their_defaults(tmp_path):
    """A checkpoint written before a config key existed (here context_width) soups with one that stores it."""
    _checkpoint(tmp_path / "a.pt", 1)
    _checkpoint(tmp_path / "b.pt", 2)
    old = torch.load(tmp_path / "a.pt", weights_only=True)
    del old["config"]["context_width"]
    torch.save(old, tmp_path / "old.pt")
    make_soup([tmp_path / "old.pt", tmp_path / "b.pt"], tmp_path / "soup.pt")
    assert load_checkpoint(tmp_path / "soup.pt").config.context_width == 0
