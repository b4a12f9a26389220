"""`pixie train --distill`: the distillation term against a closed form, and its effect on a tiny fine-tune."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from pixie_gs.model.checkpoint import load_checkpoint
from pixie_gs.model.distill import distillation_loss, kept_objects


def _softmax(z: np.ndarray) -> np.ndarray:
    e = np.exp(z - z.max())
    return e / e.sum()


def test_distillation_loss_is_kl_plus_squared_difference_over_kept_occupied_voxels():
    """Written out voxel by voxel in float64 numpy: Σ q·log(q/p) + Σ (y − t)² over the occupied voxels of
    kept objects, divided by their number; the other object and the empty voxels do not count."""
    rng = np.random.default_rng(5)
    b, k, n = 3, 4, 2
    logits, t_logits = rng.normal(size=(b, k, n, n, n)), rng.normal(size=(b, k, n, n, n))
    phys, t_phys = rng.normal(size=(b, 3, n, n, n)), rng.normal(size=(b, 3, n, n, n))
    occupied = rng.random((b, n, n, n)) < 0.6
    keep = np.array([True, False, True])
    total, count = 0.0, 0
    for i in range(b):
        for idx in np.ndindex(n, n, n):
            if not (keep[i] and occupied[(i, *idx)]):
                continue
            p = _softmax(logits[(i, slice(None), *idx)])
            q = _softmax(t_logits[(i, slice(None), *idx)])
            total += float((q * np.log(q / p)).sum())
            total += float(((phys[(i, slice(None), *idx)] - t_phys[(i, slice(None), *idx)]) ** 2).sum())
            count += 1
    got, kept = distillation_loss(*(torch.tensor(a) for a in (logits, phys, t_logits, t_phys)),
                                  torch.tensor(occupied), torch.tensor(keep))
    assert count > 0 and kept == count and float(got) == pytest.approx(total / count, rel=1e-5)
    same, _ = distillation_loss(*(torch.tensor(a) for a in (logits, phys, logits, phys)),
                                torch.tensor(occupied), torch.tensor(keep))
    assert abs(float(same)) < 1e-6


def test_distillation_loss_without_kept_voxels_is_zero_and_differentiable():
    logits = torch.randn(2, 3, 2, 2, 2, requires_grad=True)
    phys = torch.randn(2, 3, 2, 2, 2)
    term, kept = distillation_loss(logits, phys, torch.randn(2, 3, 2, 2, 2), torch.randn(2, 3, 2, 2, 2),
                                   torch.ones(2, 2, 2, 2, dtype=torch.bool), torch.tensor([False, False]))
    term.backward()
    assert kept == 0 and float(term.detach()) == 0.0 and float(logits.grad.abs().sum()) == 0.0


def test_kept_objects_leaves_out_the_skipped_kinds():
    names = ["cloth", "mugs", "metal_tools", "mugs"]
    assert kept_objects(names, [3, 0, 2, 1], ["cloth", "metal_tools"]) == [True, False, False, True]
    assert kept_objects(names, [0, 1], []) == [True, True]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """Two kinds of objects, a start checkpoint trained one epoch on them; returns (folder, data, start, flags)."""
    from pixie_gs.cli.main import main

    root = tmp_path_factory.mktemp("distill")
    data = root / "data"
    for split, count in (("train", 4), ("val", 2)):
        assert main(["generate", str(data), "--count", str(count), "--split", split, "--gaussians", "400",
                     "--classes", "sport_balls,soda_cans", "-q"]) == 0
    common = ["--device", "cpu", "--resolution", "16", "--base-channels", "4", "--multipliers", "1,2",
              "--batch-size", "2", "--seed", "3", "-q"]
    start = root / "start.pt"
    assert main(["train", str(data), "--out", str(start), "--epochs", "1", *common]) == 0
    return root, data, start, common


def _outputs(path, data) -> torch.Tensor:
    """The checkpoint's class probabilities and E, ν, ρ on the val objects' occupied voxels (no augmentation)."""
    from pixie_gs.model.batch import build_batch
    from pixie_gs.model.data import DeviceStore, load_split
    from pixie_gs.model.predict import grid_channel_names, select_inputs

    loaded = load_checkpoint(path)
    records, _ = load_split(data, "val", list(loaded.features.extra_names))
    store = DeviceStore(records, "cpu")
    batch = build_batch(store, list(range(len(store))), loaded.features)
    with torch.no_grad():
        x = select_inputs(batch.inputs, grid_channel_names(list(loaded.features.extra_names)),
                          loaded.config.input_channels)
        logits, phys = loaded.model(x)
    occ = batch.occupied.reshape(-1)
    probs = torch.softmax(logits, 1).permute(0, 2, 3, 4, 1).reshape(-1, logits.shape[1])[occ]
    return torch.cat([probs, phys.permute(0, 2, 3, 4, 1).reshape(-1, 3)[occ]], 1)


def test_distillation_holds_a_fine_tune_near_its_teacher_and_skipping_every_kind_changes_nothing(tiny_run):
    """A fast fine-tune (lr 5e-3) moves the outputs; with `--distill START --distill-weight 30` they end
    several times closer to START's on held-out objects, each epoch logs `train_distill`; skipping both kinds
    leaves the term at zero, so that run's weights equal the undistilled run's."""
    from pixie_gs.cli.main import main

    root, data, start, common = tiny_run
    tune = ["--init", str(start), "--lr", "5e-3", "--epochs", "3", *common]
    runs = {"plain": [], "distilled": ["--distill", str(start), "--distill-weight", "30"],
            "all_skipped": ["--distill", str(start), "--distill-skip", "sport_balls,soda_cans"]}
    for name, extra in runs.items():
        assert main(["train", str(data), "--out", str(root / f"{name}.pt"), *tune, *extra]) == 0
    teacher = _outputs(start, data)
    gap = {name: float(((_outputs(root / f"{name}.pt", data) - teacher) ** 2).mean()) for name in runs}
    assert gap["plain"] > 0 and gap["distilled"] < 0.3 * gap["plain"], gap
    history = load_checkpoint(root / "distilled.pt").meta["history"]
    assert all(row["train_distill"] > 0 for row in history)
    assert all(row["train_distill"] == 0 for row in load_checkpoint(root / "all_skipped.pt").meta["history"])
    plain, skipped = (load_checkpoint(root / f"{n}.pt").model.state_dict() for n in ("plain", "all_skipped"))
    assert all(torch.equal(plain[k], skipped[k]) for k in plain)


def _assert_refused(capsys, argv: list[str], out, message: str) -> None:
    """`pixie ARGV` exits 1 with one line on stderr holding `message`, and writes no checkpoint at `out`."""
    from pixie_gs.cli.main import main

    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and message in err[0], (rc, err)
    assert not out.exists()


def test_train_refuses_a_skipped_kind_no_training_object_has(tiny_run, capsys):
    """A misspelt kind would silently distil what it meant to skip: it is named and refused."""
    root, data, start, common = tiny_run
    _assert_refused(capsys, ["train", str(data), "--out", str(root / "typo.pt"), "--init", str(start), "--epochs", "1",
                             "--distill", str(start), "--distill-skip", "soda_can", *common],
                    root / "typo.pt", "no training object of kind soda_can")


@pytest.mark.parametrize("flags,message", [
    (["--resolution", "24"], "was trained on other grids (resolution 16 against 24)"),
    (["--inputs", "rgb"], "reads other input channels")])
def test_train_refuses_a_teacher_built_for_other_grids(tiny_run, capsys, flags, message):
    """The teacher runs on the student's grids: a teacher of another resolution or other input channels
    would be a meaningless pull, so it is refused in one line."""
    root, data, start, common = tiny_run
    args = [a for a in common if a not in ("--resolution", "16")] if "--resolution" in flags else common
    _assert_refused(capsys, ["train", str(data), "--out", str(root / "other.pt"), "--epochs", "1", "--distill",
                             str(start), *flags, *args], root / "other.pt", message)
