"""Material network: masked loss values, a tiny training run that learns, checkpoints, shipped model."""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
import torch

from pixie_gs.errors import InputError
from pixie_gs.materials import BACKGROUND, METAL, JELLY, NUM_CLASSES, normalize_physical
from pixie_gs.model.batch import AugmentConfig, build_batch
from pixie_gs.model.checkpoint import DEFAULT_CHECKPOINT, FeatureSpec, load_checkpoint, save_checkpoint
from pixie_gs.model.data import DeviceStore, record_from_cloud
from pixie_gs.model.predict import grid_channel_names, select_inputs
from pixie_gs.model.unet import MaterialUNet, ModelConfig, masked_loss
from pixie_gs.model.soup import ingredient_validations
from pixie_gs.splat import SplatCloud

SPEC = FeatureSpec(resolution=16)
NAMES = grid_channel_names(())


def _labelled(shape: str, seed: int) -> SplatCloud:
    """A tiny labelled object: a red jelly ball or a grey metal box shell."""
    rng = np.random.default_rng(seed)
    if shape == "ball":
        p = rng.normal(size=(1500, 3))
        p /= np.linalg.norm(p, axis=1, keepdims=True)
        rgb, mid, E, nu, rho = [0.9, 0.2, 0.2], JELLY, 4e4, 0.42, 120.0
    else:
        p = rng.uniform(-1, 1, size=(1500, 3))
        axis = rng.integers(0, 3, 1500)
        p[np.arange(1500), axis] = np.sign(p[np.arange(1500), axis])
        rgb, mid, E, nu, rho = [0.6, 0.6, 0.65], METAL, 6e10, 0.3, 2700.0
    cloud = SplatCloud.from_arrays(p, log_scales=np.full((1500, 3), np.log(0.06)), rgb=np.tile(rgb, (1500, 1)))
    n = len(cloud)
    cloud.set_materials(np.full(n, mid), np.full(n, E), np.full(n, nu), np.full(n, rho))
    return cloud


@pytest.fixture(scope="module")
def store():
    records = [record_from_cloud(_labelled(s, i), [], f"{s}{i}", s) for i, s in enumerate(["ball", "box"] * 2)]
    return DeviceStore(records, "cpu")


def test_masked_loss_counts_only_occupied_voxels():
    b, n = 1, 4
    occ = torch.zeros(b, n, n, n, dtype=torch.bool)
    occ[0, :2] = True  # 32 occupied voxels
    target_class = torch.full((b, n, n, n), BACKGROUND)
    target_class[occ] = METAL
    target_phys = torch.zeros(b, 3, n, n, n)
    logits = torch.zeros(b, NUM_CLASSES, n, n, n)  # uniform: CE = ln 8
    phys = torch.zeros(b, 3, n, n, n)
    phys[:, 1] = 0.5  # ν error 0.5 everywhere → MSE 0.25
    loss, parts = masked_loss(logits, phys, target_class, target_phys, occ)
    assert parts["ce"] == pytest.approx(math.log(8), rel=1e-6)
    assert parts["mse_nu"] == pytest.approx(0.25) and parts["mse_log_E"] == 0.0
    assert float(loss) == pytest.approx(math.log(8) + 0.25, rel=1e-6)
    # anything in unoccupied voxels is ignored
    logits[:, :, 3] = 50.0
    phys[:, :, 3] = 9.0
    loss2, _ = masked_loss(logits, phys, target_class, target_phys, occ)
    assert float(loss2) == pytest.approx(float(loss), rel=1e-6)


def test_voxel_labels_follow_the_gaussians(store):
    batch = build_batch(store, [0, 1], SPEC)
    occ = batch.occupied
    assert occ[0].sum() > 50 and occ[1].sum() > 50
    assert torch.all(batch.target_class[0][occ[0]] == JELLY)
    assert torch.all(batch.target_class[1][occ[1]] == METAL)
    assert torch.all(batch.target_class[~occ] == BACKGROUND)
    want = torch.as_tensor(normalize_physical(6e10, 0.3, 2700.0))
    got = batch.target_physical[1].permute(1, 2, 3, 0)[occ[1]]
    assert torch.allclose(got, want.expand_as(got), atol=1e-4)


def test_augmentation_keeps_labels_and_changes_the_grid(store):
    plain = build_batch(store, [1], SPEC)
    aug = build_batch(store, [1], SPEC, AugmentConfig(), 3)
    assert torch.all(aug.target_class[aug.occupied] == METAL)
    assert not torch.equal(plain.occupied, aug.occupied)  # rotated/stretched box covers other voxels


def test_tilt_augmentation_tilts_a_share_of_objects_within_its_bound(store):
    """`pixie train --tilt-deg 40`: about `tilt_share` of the objects have their up axis turned, by at most
    40°; without tilt every object keeps +z up (yaw, flips and stretch leave it), and labels follow."""
    from pixie_gs.model.batch import augmentation_matrix, object_generator

    def up_angles(cfg: AugmentConfig) -> np.ndarray:
        ups = [augmentation_matrix(object_generator(5, i), cfg, "cpu") @ torch.tensor([0.0, 0.0, 1.0])
               for i in range(400)]
        return np.array([math.degrees(math.acos(min(1.0, float(u[2] / u.norm())))) for u in ups])

    tilted = up_angles(AugmentConfig(tilt_max_deg=40.0, tilt_share=0.5))
    assert 0.4 < (tilted > 0.01).mean() < 0.6
    assert 35.0 < tilted.max() <= 40.0 + 1e-3
    assert up_angles(AugmentConfig()).max() < 0.01
    batch = build_batch(store, [1], SPEC, AugmentConfig(tilt_max_deg=40.0, tilt_share=1.0), 3)
    assert torch.all(batch.target_class[batch.occupied] == METAL)


def test_framing_augmentation_shrinks_objects_within_their_grid(store):
    """`pixie train --frame-margin-max 0.25`: each object's margin is drawn in [0.05, 0.25], so it spans
    between 0.9 and 0.5 of the grid. The other draws (yaw, flips, stretch, colour) stay those of a run
    without it: every framed object is its unframed self scaled about the grid centre, nothing else."""
    ratios = []
    for seed in range(6):
        plain = build_batch(store, [1], SPEC, AugmentConfig(), seed).means_unit[0] - 0.5
        framed = build_batch(store, [1], SPEC, AugmentConfig(margin_max=0.25), seed).means_unit[0] - 0.5
        k = float((framed * plain).sum() / (plain * plain).sum())  # least-squares scale
        assert torch.allclose(framed, k * plain, atol=1e-5)
        ratios.append(k)
    assert all(0.5 / 0.9 - 1e-6 <= k <= 1.0 + 1e-6 for k in ratios) and max(ratios) - min(ratios) > 0.1
    batch = build_batch(store, [1], SPEC, AugmentConfig(margin_max=0.25), 0)
    assert torch.all(batch.target_class[batch.occupied] == METAL)


def test_decals_paint_bounded_balls_of_one_colour_each():
    """`pixie train --decal-share S`: a share S of objects gets 2–8 balls painted, each one random colour and
    at most 0.3 of the object's extent in radius; the generator always advances by the same count, so the
    draws after it (and a run with S = 0) are unchanged."""
    from pixie_gs.model.batch import DECAL_RADIUS, MAX_DECALS, paint_decals

    rng = np.random.default_rng(0)
    means = torch.as_tensor(rng.uniform(-1, 1, (3000, 3)) * [1.0, 0.5, 0.25], dtype=torch.float32)
    rgb = torch.full((3000, 3), 0.5)
    extent = float((means.max(0).values - means.min(0).values).max())
    painted_calls = 0
    for k in range(200):
        gen_a, gen_b = torch.Generator().manual_seed(k), torch.Generator().manual_seed(k)
        out = paint_decals(gen_a, means, rgb, 0.3)
        assert paint_decals(gen_b, means, rgb, 0.0) is rgb
        assert torch.equal(torch.rand(1, generator=gen_a), torch.rand(1, generator=gen_b))
        changed = (out != rgb).any(1)
        if not changed.any():
            continue
        painted_calls += 1
        colours = torch.unique(out[changed], dim=0)
        assert 1 <= len(colours) <= MAX_DECALS and float(out.min()) >= 0.0 and float(out.max()) <= 1.0
        for colour in colours:
            members = means[(out == colour).all(1)]
            span = float(torch.cdist(members, members).max())
            assert span <= 2 * DECAL_RADIUS[1] * extent + 1e-5
    assert 0.2 < painted_calls / 200 < 0.4


def test_decals_change_colours_only(store):
    """With decals on every object, geometry and labels are those of the same seed without them; the input
    grids differ (colour channels)."""
    for seed in range(3):
        plain = build_batch(store, [0, 1], SPEC, AugmentConfig(), seed)
        decal = build_batch(store, [0, 1], SPEC, AugmentConfig(decal_share=1.0), seed)
        for a, b in zip(plain.means_unit, decal.means_unit):
            assert torch.equal(a, b)
        assert torch.equal(plain.occupied, decal.occupied) and torch.equal(plain.target_class, decal.target_class)
        assert torch.equal(plain.target_physical, decal.target_physical)
        assert not torch.equal(plain.inputs, decal.inputs)


def test_hue_shift_turns_colours_about_grey_and_keeps_draws():
    """`pixie train --hue-share S`: a share S of objects has its colours turned about the grey axis (greys stay,
    a turn by 120° maps red to green, the channel mean stays) and its saturation scaled within
    SATURATION_RANGE; always 3 draws, so a run with S = 0 sees the same numbers after it."""
    from pixie_gs.model.batch import SATURATION_RANGE, shift_hue

    rgb = torch.tensor([[0.5, 0.5, 0.5], [0.8, 0.2, 0.2], [0.3, 0.6, 0.4], [0.1, 0.2, 0.9]])
    shifted_calls = 0
    for k in range(300):
        gen_a, gen_b = torch.Generator().manual_seed(k), torch.Generator().manual_seed(k)
        out = shift_hue(gen_a, rgb, 0.5)
        assert shift_hue(gen_b, rgb, 0.0) is rgb
        assert torch.equal(torch.rand(1, generator=gen_a), torch.rand(1, generator=gen_b))
        if torch.equal(out, rgb):
            continue
        shifted_calls += 1
        assert torch.allclose(out[0], rgb[0], atol=1e-6)  # grey stays grey
        spread_in = (rgb[1:] - rgb[1:].mean(1, keepdim=True)).norm(dim=1)
        spread_out = (out[1:] - out[1:].mean(1, keepdim=True)).norm(dim=1)
        unclamped = ((out[1:] > 1e-6) & (out[1:] < 1 - 1e-6)).all(1)
        ratio = spread_out[unclamped] / spread_in[unclamped]
        assert torch.all(ratio >= SATURATION_RANGE[0] - 1e-4) and torch.all(ratio <= SATURATION_RANGE[1] + 1e-4)
        assert torch.allclose(out[1:][unclamped].mean(1), rgb[1:][unclamped].mean(1), atol=1e-5)
    assert 0.4 < shifted_calls / 300 < 0.6


def test_hue_turn_by_a_third_maps_red_to_green():
    """The turn itself, against colours known without the code: 120° about grey permutes the channels
    (red → green → blue), and saturation 0 leaves each colour's grey."""
    from pixie_gs.model.batch import turn_hue

    rgb = torch.tensor([[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.2, 0.4, 0.6]])
    assert torch.allclose(turn_hue(rgb, 2 * math.pi / 3, 1.0), rgb[:, [2, 0, 1]], atol=1e-5)
    assert torch.allclose(turn_hue(rgb, 0.3, 0.0), rgb.mean(1, keepdim=True).expand(-1, 3), atol=1e-6)


def test_hue_shift_changes_colours_only(store):
    for seed in range(3):
        plain = build_batch(store, [0, 1], SPEC, AugmentConfig(decal_share=0.5), seed)
        hued = build_batch(store, [0, 1], SPEC, AugmentConfig(decal_share=0.5, hue_share=1.0), seed)
        for a, b in zip(plain.means_unit, hued.means_unit):
            assert torch.equal(a, b)
        assert torch.equal(plain.target_class, hued.target_class)
        assert torch.equal(plain.target_physical, hued.target_physical)


def test_tiny_training_run_reduces_the_loss(store):
    torch.manual_seed(0)
    model = MaterialUNet(ModelConfig(input_channels=NAMES, projector_hidden=8, projector_out=8, base_channels=8,
                                     multipliers=[1, 2]))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    batch = build_batch(store, [0, 1, 2, 3], SPEC)
    x = select_inputs(batch.inputs, NAMES, NAMES)
    losses = []
    for _ in range(40):
        logits, phys = model(x)
        loss, _ = masked_loss(logits, phys, batch.target_class, batch.target_physical, batch.occupied)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0]
    assert np.mean(losses[-5:]) < np.mean(losses[:5])
    with torch.no_grad():
        logits, _ = model(x)
    pred = logits[:, :BACKGROUND].argmax(1)
    assert float((pred[batch.occupied] == batch.target_class[batch.occupied]).float().mean()) > 0.9


def test_checkpoint_round_trip_weights_only(tmp_path):
    torch.manual_seed(1)
    model = MaterialUNet(ModelConfig(input_channels=NAMES[:5], base_channels=8, multipliers=[1, 2]))
    spec = FeatureSpec(resolution=16, extra_names=("clip_0",))
    path = tmp_path / "m.pt"
    save_checkpoint(path, model, spec, {"note": "test"})
    raw = torch.load(path, weights_only=True, map_location="cpu")
    assert raw["normalization"]["nu"] == [0.21, 0.449]
    loaded = load_checkpoint(path)
    assert loaded.features == spec and loaded.config == model.config and loaded.meta == {"note": "test"}
    x = torch.randn(1, 5, 16, 16, 16)
    model.eval()
    with torch.no_grad():
        a, b = model(x), loaded.model(x)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


def test_bad_checkpoints_are_input_errors(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="bad.pt"):
        load_checkpoint(bad)
    other = tmp_path / "other.pt"
    torch.save({"format": "something-else"}, other)
    with pytest.raises(InputError, match="not a pixie-gs material checkpoint"):
        load_checkpoint(other)
    with pytest.raises(InputError, match="not found"):
        load_checkpoint(tmp_path / "missing.pt")


def test_shipped_checkpoint_is_small_and_loads_weights_only():
    assert DEFAULT_CHECKPOINT.is_file()
    assert os.path.getsize(DEFAULT_CHECKPOINT) <= 20 * 2 ** 20
    loaded = load_checkpoint()
    assert loaded.features.resolution == 64
    # a trained checkpoint records its validation; a soup records each of its ingredients' (soups of soups too)
    vals = [v["accuracy"] for v in ingredient_validations(loaded.meta)]
    assert vals and min(vals) > 0.95
    assert set(loaded.meta["label_ranges"]) == {"log10_E_pa", "nu", "log10_density_kg_m3"}


def _unlabelled(cloud: SplatCloud) -> SplatCloud:
    """The cloud without its label attributes (the model must not see the answer)."""
    labels = ("material_id", "E", "nu", "density", "part_id")
    for name in labels:
        del cloud.extras[name]
    cloud.property_order = [p for p in cloud.property_order if p not in labels]
    return cloud


@pytest.mark.parametrize("class_name,material,check_E", [("sport_balls", JELLY, True), ("soda_cans", METAL, False)])
def test_shipped_checkpoint_predicts_generated_ball_and_can(class_name, material, check_E):
    """Class (both) and E within half a decade (the ball). This can (seed 12345) lies on its side; the
    shipped checkpoint gets its class but puts E 2 decades low (docs/model_card.md, known weaknesses):
    E over every class is checked by the next test instead."""
    from pixie_gs.annotate import annotate_cloud
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.labels import load_class_table

    cloud, _ = build_object(load_class_table()[class_name], 12345, 4000)
    true_E = cloud.get_materials()[1]
    out = annotate_cloud(_unlabelled(cloud), device="cpu")
    mid, E, nu, rho = out.get_materials()
    assert np.mean(mid == material) > 0.95
    if check_E:
        assert abs(np.median(np.log10(E)) - np.median(np.log10(true_E))) < 0.5


def test_shipped_checkpoint_on_clean_objects_of_every_class():
    """One clean object per class (as `pixie convert` would write it; test-split seeds, 8,000 Gaussians):
    a regression guard on the shipped checkpoint's per-Gaussian material accuracy and on the share of
    Gaussians whose E lies within half a decade of their part's range in the class table (labels are
    drawn anywhere in that range, so a per-object truth is not knowable from the splat; the range is).
    Measured 0.947 and 0.925 (r30, 2026-11-26; the soup before: 0.904 and 0.870); its known misses here,
    also in docs/model_card.md: a lying metal bottle read as glass (same E and ρ, another class id), a
    guitar's stand, the tree's branches inside the crown (crown-soft, not wood). The issue's held-out targets are measured by `pixie evaluate`."""
    from pixie_gs.annotate import annotate_cloud
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table

    table = load_class_table()
    correct = total = in_range = 0
    for i, (name, spec) in enumerate(table.items()):
        cloud, _ = build_object(spec, object_seed(404, "test", i), 8000)
        true_mid = cloud.get_materials()[0]
        part = cloud.get("part_id")
        lo = np.log10([spec.parts[k].E_pa[0] for k in part]) - 0.5
        hi = np.log10([spec.parts[k].E_pa[1] for k in part]) + 0.5
        mid, E = annotate_cloud(_unlabelled(cloud), device="cpu").get_materials()[:2]
        correct += int((mid == true_mid).sum())
        in_range += int(((np.log10(E) >= lo) & (np.log10(E) <= hi)).sum())
        total += len(mid)
    assert correct / total >= 0.88, correct / total
    assert in_range / total >= 0.85, in_range / total


def test_train_resume_and_evaluate_cli_on_a_generated_dataset(tmp_path, capsys):
    """`pixie train` (1 epoch) → `--resume` to epoch 2 keeps epoch 1's history → `pixie evaluate` table;
    `--keep-epochs` leaves each epoch's own weights beside the best ones."""
    import json

    from pixie_gs.cli.main import main

    data = tmp_path / "data"
    for split, count in (("train", 3), ("val", 2), ("test", 2)):
        assert main(["generate", str(data), "--count", str(count), "--split", split, "--gaussians", "400",
                     "--classes", "sport_balls,soda_cans", "-q"]) == 0
    ckpt = tmp_path / "m.pt"
    common = ["--device", "cpu", "--resolution", "16", "--base-channels", "4", "--multipliers", "1,2",
              "--batch-size", "2", "-q"]
    assert main(["train", str(data), "--out", str(ckpt), "--epochs", "1", "--keep-epochs", *common]) == 0
    first = load_checkpoint(ckpt).meta["history"]
    assert [h["epoch"] for h in first] == [1]
    assert main(["train", str(data), "--out", str(ckpt), "--epochs", "2", "--resume", "--keep-epochs", *common]) == 0
    kept = {n: load_checkpoint(tmp_path / f"m.epoch{n:02d}.pt") for n in (1, 2)}
    assert sorted(p.name for p in tmp_path.glob("m.epoch*.pt")) == ["m.epoch01.pt", "m.epoch02.pt"]
    assert [kept[n].meta["epoch"] for n in (1, 2)] == [1, 2]
    weights = {n: kept[n].model.state_dict() for n in (1, 2)}
    assert any(not torch.equal(weights[1][k], weights[2][k]) for k in weights[1])  # epoch 2 trained on
    best = load_checkpoint(ckpt)
    assert all(torch.equal(v, weights[best.meta["best_epoch"]][k]) for k, v in best.model.state_dict().items())
    state = torch.load(str(ckpt) + ".state.pt", weights_only=True)
    history = json.loads(state["history_json"])
    assert [h["epoch"] for h in history] == [1, 2] and history[0] == first[0]
    assert state["step"] == 4  # 2 batches per epoch, 2 epochs
    # a resume whose time budget the run already spent says so in one line instead of ending without an epoch
    capsys.readouterr()
    spent = max(1, int(state["elapsed_s"]))
    assert main(["train", str(data), "--out", str(ckpt), "--epochs", "3", "--resume", "--time-budget-s", str(spent),
                 *common]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "m.pt.state.pt" in err[0] and "already spent" in err[0], err
    assert torch.load(str(ckpt) + ".state.pt", weights_only=True)["step"] == 4  # untouched
    capsys.readouterr()
    report = tmp_path / "metrics.json"
    assert main(["evaluate", str(ckpt), str(data), "--split", "test", "--device", "cpu", "--json", str(report), "-q"]) == 0
    table = capsys.readouterr().out
    assert "mat.acc" in table and "per-class accuracy" in table
    metrics = json.loads(report.read_text())
    assert metrics["objects"] == 2 and metrics["gaussian"]["count"] > 500
    assert 0.0 <= metrics["voxel"]["accuracy"] <= 1.0
    assert metrics["voxel"]["mse_avg"] == pytest.approx(np.mean([metrics["voxel"][f"mse_{k}"]
                                                                 for k in ("log_E", "nu", "log_rho")]))
    assert main(["train", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x.pt"), "--device", "cpu", "-q"]) == 1


# ------------------------------------------------------------------ outputs inside physics (issue 12)
def _dark_rod() -> SplatCloud:
    """A dark 0.6 m rod of 20k Gaussians: the shipped network's raw E head extrapolates above its labels here."""
    import trimesh

    from pixie_gs.convert import mesh_to_splat

    rng = np.random.default_rng(0)
    return mesh_to_splat(trimesh.creation.cylinder(0.1, 0.6), 20000, rng, rgb=np.array([0.1, 0.1, 0.1], np.float32),
                         opacity=0.9)


@pytest.mark.parametrize("bias", [0.0, 3.0, -3.0])
def test_annotate_outputs_stay_inside_label_ranges(bias, monkeypatch):
    """E, ν, ρ lie inside the checkpoint's label ranges — themselves inside the class table's extremes, the
    table its training labels came from — on an input where an older shipped network's raw head gave E
    far above them (bias 0), and when the real network's last layer is pushed far outside (bias ±3: raw
    E 10^14 / 10^-1 Pa)."""
    from pixie_gs import annotate as ann
    from pixie_gs.dataset.labels import table_extremes
    from pixie_gs.model.predict import label_ranges

    loaded = load_checkpoint(None, "cpu")
    with torch.no_grad():
        loaded.model.physical_head.bias += bias
    monkeypatch.setitem(ann._CACHE, (str(DEFAULT_CHECKPOINT), "cpu"), loaded)
    out = ann.annotate_cloud(_dark_rod(), device="cpu")
    _, E, nu, rho = out.get_materials()
    r = label_ranges(loaded.meta)
    tol = 1e-4
    e_lo, e_hi = table_extremes()["E"]  # the training labels were drawn from the class table: inside its extremes
    # within one 4th-decimal step: the stored ranges are widened outwards at the 4th decimal (r75 was trained on
    # a teacher pool whose labels are clipped to the table, stop 57, and stores 10.9031 for 8e10 Pa = 10^10.90309)
    step = 1e-4 + 1e-6
    assert r["log10_E_pa"][0] >= np.log10(e_lo) - step and r["log10_E_pa"][1] <= np.log10(e_hi) + step
    assert np.log10(E).max() <= r["log10_E_pa"][1] + tol and np.log10(E).min() >= r["log10_E_pa"][0] - tol
    assert nu.max() < 0.5 and nu.max() <= r["nu"][1] + tol and nu.min() >= r["nu"][0] - tol
    assert np.log10(rho).max() <= r["log10_density_kg_m3"][1] + tol
    assert np.log10(rho).min() >= r["log10_density_kg_m3"][0] - tol
    if bias > 0:  # every value pinned at the top of the range
        assert np.log10(E).min() == pytest.approx(r["log10_E_pa"][1], abs=1e-3)
    if bias < 0:
        assert np.log10(E).max() == pytest.approx(r["log10_E_pa"][0], abs=1e-3)


def test_training_label_ranges_keep_a_teacher_clamp_edge():
    """Labels already at a stored range's edge (a teacher checkpoint's outputs, clamped to its 4-decimal range)
    give back that range, not one widened a step by float32 noise: distilling generation after generation
    would otherwise push the clamp out by 1e-4 decades each time. Widening outwards still holds for others."""
    from types import SimpleNamespace

    from pixie_gs.model.train import training_label_ranges

    edge = normalize_physical(np.array([10**3.9032, 10**10.9031]), np.array([0.15, 0.48]),
                              np.array([10**1.7407, 10**3.871]))
    r = training_label_ranges([SimpleNamespace(physical=edge)])
    assert r["log10_E_pa"] == [3.9032, 10.9031] and r["log10_density_kg_m3"] == [1.7407, 3.871]
    inner = normalize_physical(np.array([10**4.00004, 10**9.99996]), np.array([0.2, 0.4]), np.array([100.0, 1000.0]))
    r = training_label_ranges([SimpleNamespace(physical=inner)])
    assert r["log10_E_pa"] == [4.0, 10.0]  # 4.00004 floors to 4.0, 9.99996 ceils to 10.0


def test_label_ranges_from_meta_and_nu_cap():
    from pixie_gs.model.predict import label_ranges

    assert label_ranges({})["log10_E_pa"] == [3.018, 10.882]
    r = label_ranges({"label_ranges": {"log10_E_pa": [4.0, 11.0], "nu": [0.1, 0.6], "log10_density_kg_m3": "bad"}})
    assert r["log10_E_pa"] == [4.0, 11.0] and r["nu"] == [0.1, 0.49] and r["log10_density_kg_m3"] == [1.703, 3.871]


# ------------------------------------------------------------------ confidence (issue 12)
def test_in_distribution_score_from_stored_statistics():
    """RMS z-score d against meta["feature_stats"]: 1 up to OOD_FREE_Z, then a Gaussian fall-off."""
    from pixie_gs.model.predict import OOD_FREE_Z, OOD_WIDTH, in_distribution_score

    meta = {"feature_stats": {"mean": [0.0, 1.0, 2.0], "std": [1.0, 0.5, 2.0]}}
    assert in_distribution_score({}, np.zeros(3)) == 1.0  # no statistics: no opinion
    assert in_distribution_score(meta, np.array([0.5, 1.25, 3.0])) == 1.0  # z = 0.5 each
    f = np.array([2.0, 2.0, 6.0])  # z = 2, 2, 2 → d = 2
    want = math.exp(-0.5 * ((2.0 - OOD_FREE_Z) / OOD_WIDTH) ** 2)
    assert in_distribution_score(meta, f) == pytest.approx(want)
    assert in_distribution_score(meta, np.zeros(4)) == 1.0  # mismatched length: ignored


def test_in_distribution_score_takes_the_nearest_look():
    """With `groups` (capture-like, clean) the distance is the smallest to the pooled statistics or a group:
    an object at one group's middle is in distribution even when it is far from the pooled statistics, one
    far from all of them is not."""
    from pixie_gs.model.predict import in_distribution_score

    pooled = {"mean": [0.5, 0.5], "std": [0.05, 0.05]}
    groups = [{"name": "capture-like", "mean": [0.0, 0.0], "std": [0.1, 0.1]},
              {"name": "clean", "mean": [1.0, 1.0], "std": [0.1, 0.1]}]
    at_clean = np.array([1.0, 1.0])
    assert in_distribution_score({"feature_stats": pooled}, at_clean) < 1e-3  # z = 10 from the pooled middle
    assert in_distribution_score({"feature_stats": {**pooled, "groups": groups}}, at_clean) == 1.0
    assert in_distribution_score({"feature_stats": {**pooled, "groups": groups}}, np.array([0.5, 3.0])) < 1e-3
    broken = [{"name": "clean", "mean": [1.0], "std": [0.1]}]  # wrong length: ignored, pooled used
    assert in_distribution_score({"feature_stats": {**pooled, "groups": broken}}, at_clean) < 1e-3
    assert in_distribution_score({"feature_stats": {**pooled, "groups": groups}}, np.array([0.5, 0.5])) == 1.0


def test_stats_by_look_keeps_the_weights_and_the_pooled_statistics(tmp_path):
    """`python -m pixie_gs.model.stats CKPT --by-look`: groups of the capture-like and the clean objects
    are added; the checkpoint's own pooled statistics and every weight stay as they were."""
    from pixie_gs.model.stats import main as stats_main

    ckpt = tmp_path / "m.pt"
    ckpt.write_bytes(DEFAULT_CHECKPOINT.read_bytes())
    before = torch.load(ckpt, weights_only=True)
    stats_main([str(ckpt), "--count", "12", "--classes", "sport_balls,soda_cans", "--gaussians", "1500,3000",
                "--realistic-share", "0.5", "--by-look"])  # objects 0-9 capture-like, 10-11 clean
    after = torch.load(ckpt, weights_only=True)
    old, new = before["meta"]["feature_stats"], after["meta"]["feature_stats"]
    assert {k: new[k] for k in ("mean", "std", "objects")} == {k: old[k] for k in ("mean", "std", "objects")}
    assert [(g["name"], g["objects"]) for g in new["groups"]] == [("capture-like", 10), ("clean", 2)]
    assert new["groups"][1]["mean"][new["channels"].index("sh_energy")] == 0.0  # clean: no view-dependent colour
    assert new["groups_source"]["gaussians"] == [1500, 3000]
    assert all(torch.equal(before["state_dict"][k], after["state_dict"][k]) for k in before["state_dict"])
    with pytest.raises(SystemExit):  # all clean: no capture-like group to describe
        stats_main([str(ckpt), "--count", "2", "--classes", "sport_balls", "--by-look"])
    assert torch.load(ckpt, weights_only=True)["meta"] == after["meta"]


def test_stats_copy_from_moves_the_statistics_and_nothing_else(tmp_path, capsys):
    """`python -m pixie_gs.model.stats CKPT --copy-from OTHER`: CKPT gets OTHER's grid statistics (groups
    included) and its name, its weights and label ranges stay; a donor without statistics, or with another
    feature grid, is refused in one line and CKPT is left as it was."""
    from pixie_gs.model.stats import main as stats_main

    shipped = torch.load(DEFAULT_CHECKPOINT, weights_only=True)
    ckpt, donor, bare, other_grid = (tmp_path / n for n in ("m.pt", "donor.pt", "bare.pt", "grid.pt"))
    torch.save({**shipped, "meta": {**shipped["meta"], "feature_stats": {"objects": 1, "mean": [0.0], "std": [1.0]}}},
               ckpt)
    torch.save(shipped, donor)
    torch.save({**shipped, "meta": {k: v for k, v in shipped["meta"].items() if k != "feature_stats"}}, bare)
    torch.save({**shipped, "features": {**shipped["features"], "resolution": 32}}, other_grid)
    before = torch.load(ckpt, weights_only=True)
    stats_main([str(ckpt), "--copy-from", str(donor)])
    after = torch.load(ckpt, weights_only=True)
    assert after["meta"]["feature_stats"] == shipped["meta"]["feature_stats"] and "groups" in after["meta"]["feature_stats"]
    assert after["meta"]["feature_stats_from"] == "donor.pt"
    assert after["meta"]["label_ranges"] == before["meta"]["label_ranges"]
    assert all(torch.equal(before["state_dict"][k], after["state_dict"][k]) for k in before["state_dict"])
    for bad, words in ((bare, "no grid statistics"), (other_grid, "feature grid differs")):
        with pytest.raises(SystemExit):
            stats_main([str(ckpt), "--copy-from", str(bad)])
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert words in err and bad.name in err
        assert torch.load(ckpt, weights_only=True)["meta"] == after["meta"]
    with pytest.raises(SystemExit):  # copied or computed, not both
        stats_main([str(ckpt), "--copy-from", str(donor), "--by-look"])
    assert "not allowed with" in capsys.readouterr().err


def test_annotate_writes_confidence_and_warns_when_unlike_training(monkeypatch, capsys):
    """Per-Gaussian `confidence` in [0, 1]; with training statistics far from this object the
    in-distribution factor drops to ~0 and annotate says the materials are a guess."""
    from pixie_gs import annotate as ann
    from pixie_gs.progress import set_quiet

    loaded = load_checkpoint(None, "cpu")
    monkeypatch.setitem(ann._CACHE, (str(DEFAULT_CHECKPOINT), "cpu"), loaded)
    set_quiet(False)
    rod = _dark_rod()
    out = ann.annotate_cloud(rod, device="cpu")
    conf = out.get("confidence")
    assert conf.shape == (len(rod),) and 0.0 <= conf.min() and conf.max() <= 1.0 and conf.mean() > 0.3
    n_channels = len(grid_channel_names(loaded.features.extra_names)) + 1
    loaded.meta = {**loaded.meta, "feature_stats": {"mean": [50.0] * n_channels, "std": [0.01] * n_channels}}
    capsys.readouterr()
    far = ann.annotate_cloud(rod, device="cpu").get("confidence")
    assert far.max() < 1e-3
    assert "treat its materials as a guess" in capsys.readouterr().err


def _random_unet(channels: list[str], seed: int = 3) -> MaterialUNet:
    """A shipped-size network with random weights everywhere (the zero-initialised convolutions too)."""
    torch.manual_seed(seed)
    model = MaterialUNet(ModelConfig(input_channels=channels))
    with torch.no_grad():
        for module in model.modules():
            if isinstance(module, torch.nn.Conv3d):
                torch.nn.init.normal_(module.weight, std=1.0 / math.sqrt(module.weight[0].numel()))
                torch.nn.init.normal_(module.bias, std=0.3)
            elif isinstance(module, torch.nn.GroupNorm):
                torch.nn.init.uniform_(module.weight, 0.5, 1.5)
                torch.nn.init.normal_(module.bias, std=0.3)
    return model.eval()


def _example_grid(name: str = "tree"):
    """The 64³ feature grid (1, C, 64, 64, 64) of a shipped example splat and its channel names."""
    from pixie_gs.field import feature_grid
    from pixie_gs.splat import read_splat

    path = DEFAULT_CHECKPOINT.parent.parent / "examples" / f"{name}.ply"
    grid = feature_grid(read_splat(path), 64, [])
    return torch.as_tensor(grid.values)[None], grid.channels, torch.as_tensor(grid.occupancy)[None]


def test_cpu_inference_matches_a_float64_evaluation():
    """The CPU inference path (`_forward`) computes the network's function to float32 accuracy: on a mostly
    empty 64³ grid, where a float32 E[x²]−E[x]² GroupNorm is ~1e-2 off, logits stay within 1e-3 of a
    float64 evaluation and every occupied voxel whose float64 top two classes are apart gets its class."""
    import copy

    from pixie_gs.model.checkpoint import LoadedModel
    from pixie_gs.model.predict import _forward

    values, channels, occupied = _example_grid()
    model = _random_unet(channels)
    loaded = LoadedModel(model, model.config, FeatureSpec(), {}, "random")
    logits, physical = _forward(loaded, values, channels)
    with torch.no_grad():
        ref_logits, ref_physical = copy.deepcopy(model).double()(values.double())
    ref_physical = ref_physical.clamp(-1, 1)  # the label ranges of a checkpoint without meta: [-1, 1]
    assert float((logits.double() - ref_logits).abs().max()) < 1e-3 * float(ref_logits.abs().max())
    assert float((physical.double() - ref_physical).abs().max()) < 1e-3
    top2 = ref_logits[:, :BACKGROUND].topk(2, dim=1).values
    clear = occupied & (top2[:, 0] - top2[:, 1] > 1e-3)
    same = logits[:, :BACKGROUND].argmax(1) == ref_logits[:, :BACKGROUND].argmax(1)
    assert bool(same[clear].all()) and int(clear.sum()) > 1000


@pytest.mark.parametrize("config,batch,empty", [
    (dict(), 1, 0.9),  # the shipped shape, mostly empty space
    (dict(multipliers=[1, 2], res_blocks=2, dropout=0.2), 2, 0.5),  # a batch runs sample by sample
    (dict(base_channels=8, projector_hidden=12, projector_out=12), 1, 0.0),  # no empty voxel at all
    (dict(base_channels=8), 1, 1.0),  # nothing but empty space
    (dict(base_channels=8, context_width=16), 2, 0.7),  # with the object-context branch
])
def test_fast_cpu_forward_is_the_module_forward(config, batch, empty):
    """`infer.fast_forward` (oneDNN convolutions, distinct-row projector, in-place ops) = `model(x)`."""
    from pixie_gs.model.infer import fast_forward, fast_path_applies

    model = MaterialUNet(ModelConfig(input_channels=NAMES, **config))
    with torch.no_grad():
        for p in model.parameters():
            p.normal_(0.0, 0.3)
    model.eval()
    gen = torch.Generator().manual_seed(7)
    x = torch.randn(batch, len(NAMES), 16, 16, 16, generator=gen)
    x[torch.rand(batch, 1, 16, 16, 16, generator=gen).expand_as(x) < empty] = 0.0
    assert fast_path_applies(model, x)
    with torch.no_grad():
        ref = copy_double(model)(x.double())
        logits, physical = fast_forward(model, x)
        plain = model(x)
    for got, want, module in zip((logits, physical), ref, plain):
        assert got.shape == want.shape and got.dtype == torch.float32
        scale = float(want.abs().max()) + 1e-6
        assert float((got.double() - want).abs().max()) < 2e-4 * scale  # as close to float64 as the module
        assert float((module.double() - want).abs().max()) < 2e-4 * scale
    assert not fast_path_applies(model.train(), x) and not fast_path_applies(model.eval(), x.double())


def copy_double(model: MaterialUNet) -> MaterialUNet:
    """A float64 copy of `model` (the reference the float32 paths are held to)."""
    import copy

    return copy.deepcopy(model).double()


def test_group_norm_statistics_do_not_cancel():
    """`infer._group_norm` on channels-last data whose mean is large next to its spread (the case where
    PyTorch's channels-last kernel loses digits) matches a float64 GroupNorm."""
    from pixie_gs.model.infer import _group_norm

    gen = torch.Generator().manual_seed(0)
    x = torch.full((1, 16, 64, 64, 64), 8.0)  # empty space: one value, shifted by a bias
    solid = torch.rand(64, 64, 64, generator=gen) < 0.1
    x[:, :, solid] += torch.randn(16, int(solid.sum()), generator=gen)
    x = x.contiguous(memory_format=torch.channels_last_3d)
    norm = torch.nn.GroupNorm(8, 16).eval()
    with torch.no_grad():
        norm.weight.uniform_(0.5, 1.5)
        ref = torch.nn.functional.group_norm(x.double(), 8, norm.weight.double(), norm.bias.double(), norm.eps)
        got = _group_norm(x, norm)
    assert got.is_contiguous(memory_format=torch.channels_last_3d)
    assert float((got.double() - ref).abs().max()) < 1e-4


def test_non_finite_weight_is_named_wherever_it_is(tmp_path):
    """The finiteness check runs over all weights at once; the error still names the damaged one."""
    torch.manual_seed(2)
    model = MaterialUNet(ModelConfig(input_channels=NAMES, base_channels=8, multipliers=[1, 2]))
    path = tmp_path / "m.pt"
    save_checkpoint(path, model, SPEC)
    payload = torch.load(path, weights_only=True)
    key = list(payload["state_dict"])[-3]
    payload["state_dict"][key].view(-1)[1:3] = float("inf")
    torch.save(payload, path)
    with pytest.raises(InputError, match=f"weight '{key}' holds NaN or inf \\(2 values\\)"):
        load_checkpoint(path)


@pytest.mark.parametrize("flag,value", [("--tilt-deg", "nan"), ("--tilt-deg", "120"), ("--tilt-share", "1.5")])
def test_train_rejects_a_tilt_outside_its_range(tmp_path, capsys, flag, value):
    from pixie_gs.cli.main import main

    rc = main(["train", str(tmp_path), "--out", str(tmp_path / "m.pt"), flag, value, "--device", "cpu", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "--tilt-deg must be within 0–90" in err[0], (rc, err)
    assert not (tmp_path / "m.pt").exists()


def test_learning_rate_reaches_lr_after_the_warm_up_steps_then_decays():
    """The schedule is linear warm-up over `warmup_steps`, then cosine decay to 0 at the last step: a
    120-step fine-tune with the default 100-step warm-up peaks at a third of --lr (warm-up and cosine cross);
    with 10 warm-up steps it holds nearly all of it (the case that made stop 46's overfit check weak)."""
    from pixie_gs.model.train import TrainConfig, learning_rate

    def rates(warm: int) -> list[float]:
        cfg = TrainConfig(lr=1.0, warmup_steps=warm)
        return [learning_rate(cfg, s, 120, 0.0) for s in range(120)]

    slow, quick = rates(100), rates(10)
    assert 0.3 < max(slow) < 0.35 and 40 < slow.index(max(slow)) < 60
    assert quick[9] == pytest.approx(0.5 * (1 + math.cos(math.pi * 9 / 120)))  # full rate times the cosine
    assert quick[0] == pytest.approx(0.1) and max(quick) > 0.98
    assert rates(0)[0] == pytest.approx(1.0) and quick[-1] < 1e-3


def test_train_rejects_a_negative_warm_up(tmp_path, capsys):
    from pixie_gs.cli.main import main

    rc = main(["train", str(tmp_path), "--out", str(tmp_path / "m.pt"), "--warmup-steps", "-1", "--device", "cpu", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "--warmup-steps must be ≥ 0" in err[0], (rc, err)


@pytest.mark.parametrize("flag,value,message", [
    ("--context-width", "2048", "--context-width must be ≤ 1024"), ("--base-channels", "1500", "--base-channels must be ≤ 1024"),
    ("--res-blocks", "17", "--res-blocks must be ≤ 16"), ("--resolution", "4", "--resolution must be ≥ 8"),
    ("--multipliers", "1,2,100", "--multipliers must be 1 to 6 integers")])
def test_train_refuses_a_network_the_checkpoint_loader_would_refuse(tmp_path, capsys, flag, value, message):
    """Widths above the loader's ranges (model/checkpoint.py: 1024 channels, 16 residual blocks, grids of
    8–512, multipliers 1–64) stop before any data is read, with one line, instead of training a checkpoint
    that `annotate` then refuses."""
    from pixie_gs.cli.main import main

    rc = main(["train", str(tmp_path), "--out", str(tmp_path / "m.pt"), flag, value, "--device", "cpu", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and message in err[0], (rc, err)
    assert not (tmp_path / "m.pt").exists()


@pytest.mark.parametrize("args,message", [
    (["--anchor-weight", "0.5"], "--anchor-weight needs --init"),
    (["--anchor-weight", "-1", "--init", "x.pt"], "--anchor-weight must be a finite number ≥ 0"),
    (["--anchor-weight", "nan", "--init", "x.pt"], "--anchor-weight must be a finite number ≥ 0"),
    (["--distill-skip", "cloth"], "--distill-skip needs --distill"),
    (["--distill-weight", "2"], "--distill-weight needs --distill"),
    (["--distill", "missing.pt"], "missing.pt"),
    (["--distill", "x.pt", "--distill-weight", "-1"], "--distill-weight must be a finite number ≥ 0"),
    (["--distill", "x.pt", "--distill-weight", "inf"], "--distill-weight must be a finite number ≥ 0"),
    (["--teacher-pool-repeat", "0"], "--teacher-pool-repeat must be ≥ 1"),
    (["--teacher-pool-repeat", "2"], "--teacher-pool-repeat needs --teacher-pool"),
    (["--teacher-pool", "no_pool_here"], "no_pool_here")])
def test_train_refuses_a_fine_tune_term_it_cannot_apply(tmp_path, capsys, args, message):
    """`--anchor-weight`, `--distill` and `--teacher-pool` (tests/test_distill.py) with what they need missing or
    out of range: one line, no checkpoint."""
    from pixie_gs.cli.main import main

    rc = main(["train", str(tmp_path), "--out", str(tmp_path / "m.pt"), *args, "--device", "cpu", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and message in err[0], (rc, err)
    assert not (tmp_path / "m.pt").exists()


def test_anchor_weight_keeps_a_fine_tune_near_its_start_and_the_log_measures_the_drift(tiny_run, tmp_path):
    """Fine-tuning the same start weights on the same data and seed, `--anchor-weight` (L2-SP) ends several
    times closer to the start than no anchor; each epoch's logged `drift_sq` is Σ (θ − θ_start)² of that
    epoch's weights, recomputed here from the two checkpoint files; `--resume` measures from the same start."""
    from pixie_gs.cli.main import main

    _, data, start, common = tiny_run

    def distance(a, b) -> float:
        wa, wb = a.model.state_dict(), b.model.state_dict()
        names = [n for n, _ in a.model.named_parameters()]
        return float(sum(((wa[n].double() - wb[n].double()) ** 2).sum() for n in names))

    drift = {}
    for weight in ("0", "1000"):
        out = tmp_path / f"ft{weight}.pt"
        tune = ["--init", str(start), "--lr", "5e-3", "--anchor-weight", weight, "--keep-epochs", *common]
        assert main(["train", str(data), "--out", str(out), "--epochs", "1", *tune]) == 0
        assert main(["train", str(data), "--out", str(out), "--epochs", "2", "--resume", *tune]) == 0
        history = load_checkpoint(tmp_path / f"ft{weight}.epoch02.pt").meta["history"]
        for row in history:
            kept = load_checkpoint(tmp_path / f"ft{weight}.epoch{row['epoch']:02d}.pt")
            assert row["drift_sq"] == pytest.approx(distance(kept, load_checkpoint(start)), rel=1e-3, abs=1e-6)
        drift[weight] = history[-1]["drift_sq"]
    assert drift["0"] > 0 and drift["1000"] < 0.2 * drift["0"], drift


def test_object_context_adds_one_vector_per_object_that_depends_on_the_whole_grid():
    """The branch adds, at the bottleneck, the same vector to every voxel of an object: a function of the
    whole grid (an input far from a voxel changes it), different for each object of a batch."""
    torch.manual_seed(3)
    model = MaterialUNet(ModelConfig(input_channels=NAMES, base_channels=8, multipliers=[1, 2], context_width=8))
    with torch.no_grad():
        for p in model.parameters():
            p.normal_(0.0, 0.3)
    model.eval()
    added = []
    model.context.register_forward_hook(lambda module, args, out: added.append(out - args[0]))
    x = torch.zeros(2, len(NAMES), 16, 16, 16)
    x[:, :, 2:5, 2:5, 2:5] = 1.0
    x[1, :, 11:14, 11:14, 11:14] = 2.0  # the second object differs only far from the first block
    with torch.no_grad():
        model(x)
    term = added[0]  # (2, C, 8, 8, 8)
    assert torch.allclose(term, term[:, :, :1, :1, :1].expand_as(term), atol=1e-5)  # one vector per object
    assert float((term[0] - term[1]).abs().max()) > 1e-3


def test_init_grows_a_checkpoint_by_a_context_branch_with_the_same_outputs(tmp_path):
    """`pixie train --init OLD --context-width W`: OLD's weights, the new branch at zero, so the grown
    network computes exactly what OLD did; any other change of configuration is refused."""
    from pixie_gs.model.train import load_init_weights

    torch.manual_seed(4)
    old_config = ModelConfig(input_channels=NAMES, base_channels=8, multipliers=[1, 2])
    old = MaterialUNet(old_config).eval()
    with torch.no_grad():
        for p in old.parameters():
            p.normal_(0.0, 0.3)
    new_config = ModelConfig(input_channels=NAMES, base_channels=8, multipliers=[1, 2], context_width=16)
    grown = MaterialUNet(new_config).eval()
    assert load_init_weights(grown, old, old_config, new_config, "old.pt") is True
    x = torch.randn(2, len(NAMES), 16, 16, 16)
    with torch.no_grad():
        for a, b in zip(old(x), grown(x)):
            assert torch.equal(a, b)
    assert load_init_weights(MaterialUNet(old_config), old, old_config, old_config, "old.pt") is False
    with pytest.raises(InputError, match="different network"):
        wider = ModelConfig(input_channels=NAMES, base_channels=16, multipliers=[1, 2], context_width=16)
        load_init_weights(MaterialUNet(wider), old, old_config, wider, "old.pt")
    with pytest.raises(InputError, match="different network"):  # a branch is never dropped
        load_init_weights(MaterialUNet(old_config), grown, new_config, old_config, "grown.pt")
    path = tmp_path / "grown.pt"  # and the grown network survives a checkpoint round trip
    save_checkpoint(path, grown, SPEC, {})
    loaded = load_checkpoint(path)
    assert loaded.config.context_width == 16
    with torch.no_grad():
        assert torch.equal(loaded.model(x)[1], grown(x)[1])
