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


def test_turned_cloud_turns_centres_and_covariances_and_keeps_view_dependent_energy():
    """R·μ and R Σ Rᵀ, written out in float64 here, for a random proper rotation; the SH energy channel the
    network reads is the same before and after."""
    from pixie_gs.dataset.teacher_pool import turned_cloud
    from pixie_gs.field import per_gaussian_channels
    from pixie_gs.splat import SplatCloud

    rng = np.random.default_rng(11)
    n = 50
    cloud = SplatCloud.from_arrays(rng.normal(size=(n, 3)), rng.normal(-3, 0.5, (n, 3)), rng.normal(size=(n, 4)),
                                   rng.normal(size=n), rng.normal(size=(n, 3)), rng.normal(0, 0.2, (n, 45)))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot = q * np.sign(np.linalg.det(q))
    out = turned_cloud(cloud, rot)
    cov = cloud.covariances().astype(np.float64)
    assert np.allclose(out.means, cloud.means.astype(np.float64) @ rot.T, atol=1e-5)
    assert np.allclose(out.covariances(), rot @ cov @ rot.T, atol=1e-6 * np.abs(cov).max())
    assert np.allclose(per_gaussian_channels(out, [])[0], per_gaussian_channels(cloud, [])[0])


def test_teacher_pool_turns_each_object_upright_and_labels_it_as_training_reads_it(tiny_run, tmp_path):
    """A generated mug written lying on its side (its up declared +y, as `pixie convert` declares a glTF's):
    the pool object stands upright again (its height along z is the mug's), is thinned to the cap, carries the
    teacher's materials of that very object read z-up (what the label loss and the distillation term see),
    and the source file is left as it was; a second pool into the same folder is refused."""
    import hashlib

    from pixie_gs.annotate import annotate_cloud
    from pixie_gs.cli.main import main
    from pixie_gs.dataset.loader import list_objects, load_object
    from pixie_gs.dataset.teacher_pool import POOL_CLASS, make_pool
    from pixie_gs.errors import InputError

    _, _, start, _ = tiny_run
    assert main(["generate", str(tmp_path / "src"), "--count", "1", "--split", "test", "--gaussians", "3000",
                 "--classes", "mugs", "--clean", "-q"]) == 0
    upright, _ = load_object(list_objects(tmp_path / "src", "test")[0])
    z_to_y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # +z → +y
    from pixie_gs.dataset.teacher_pool import turned_cloud

    lying = turned_cloud(upright, z_to_y)
    lying.comments = ["pixie up 0 1 0"]
    src = tmp_path / "lying_mug.ply"
    lying.write(src)
    before = hashlib.sha256(src.read_bytes()).hexdigest()
    index = make_pool(tmp_path / "pool", [src], str(start), "cpu", max_gaussians=1000)
    assert hashlib.sha256(src.read_bytes()).hexdigest() == before
    assert index["count"] == 1 and index["objects"][0]["class"] == POOL_CLASS
    obj, record = load_object(list_objects(tmp_path / "pool", "train")[0])
    assert record["class"] == POOL_CLASS and len(obj) == 1000
    height = np.ptp(upright.means[:, 2])
    assert abs(np.ptp(obj.means[:, 2]) - height) < 0.1 * height, (np.ptp(obj.means, 0), height)
    read = annotate_cloud(obj, str(start), "cpu", up="z").get_materials()
    for got, want in zip(obj.get_materials(), read):
        assert np.array_equal(got, want)
    assert set(np.unique(obj.get("part_id"))) == {0}
    with pytest.raises(InputError, match="already holds a teacher pool"):
        make_pool(tmp_path / "pool", [src], str(start), "cpu", max_gaussians=1000)


def test_teacher_pool_labels_stay_inside_the_class_table(tiny_run, tmp_path, monkeypatch):
    """A teacher whose stored E range reaches past the class table (10^11.5 Pa) and whose head is pushed to
    its top labels the pool at the table's highest E (8e10 Pa) instead, so a student trained on it stores
    10.9031 decades, not the teacher's edge: the widening at the 4th decimal does not pass from one
    generation of checkpoints to the next (r59's 10.9032)."""
    from types import SimpleNamespace

    from pixie_gs import annotate as ann
    from pixie_gs.dataset.labels import table_extremes
    from pixie_gs.dataset.loader import list_objects, load_object
    from pixie_gs.dataset.teacher_pool import make_pool
    from pixie_gs.materials import normalize_physical
    from pixie_gs.model.train import training_label_ranges

    _, _, start, _ = tiny_run
    teacher = load_checkpoint(str(start), "cpu")
    teacher.meta = {**teacher.meta, "label_ranges": {**teacher.meta["label_ranges"], "log10_E_pa": [3.0, 11.5]}}
    with torch.no_grad():
        teacher.model.physical_head.bias += 3.0
    monkeypatch.setitem(ann._CACHE, (str(start), "cpu"), teacher)
    make_pool(tmp_path / "pool", [_a_generated_object(tmp_path)], str(start), "cpu", max_gaussians=500)
    obj, _ = load_object(list_objects(tmp_path / "pool", "train")[0])
    _, E, nu, rho = obj.get_materials()
    ex = table_extremes()
    assert ex["E"][1] == 8e10 and np.all(E == np.float32(8e10)), (E.min(), E.max())
    assert nu.min() >= ex["nu"][0] and nu.max() <= ex["nu"][1]
    assert rho.min() >= np.float32(ex["density"][0]) and rho.max() <= np.float32(ex["density"][1])
    stored = training_label_ranges([SimpleNamespace(physical=normalize_physical(E, nu, rho))])
    assert stored["log10_E_pa"][1] == 10.9031


def test_train_adds_the_teacher_pool_repeated_and_distils_on_it(tiny_run, tmp_path):
    """`--teacher-pool P --teacher-pool-repeat 3`: the run trains on the 4 generated objects and 3 listings of
    P's one object; with every generated kind skipped, the distillation term comes from the pool alone."""
    from pixie_gs.cli.main import main
    from pixie_gs.dataset.teacher_pool import make_pool

    root, data, start, common = tiny_run
    make_pool(tmp_path / "pool", [_a_generated_object(tmp_path)], str(start), "cpu", max_gaussians=800)
    out = tmp_path / "pooled.pt"
    assert main(["train", str(data), "--out", str(out), "--init", str(start), "--epochs", "1",
                 "--teacher-pool", str(tmp_path / "pool"), "--teacher-pool-repeat", "3", "--distill", str(start),
                 "--distill-skip", "sport_balls,soda_cans", "--lr", "5e-3", *common]) == 0
    meta = load_checkpoint(out).meta
    assert meta["train_objects"] == 4 + 3
    assert meta["train_config"]["teacher_pool_repeat"] == 3
    assert all(row["train_distill"] > 0 for row in meta["history"])


def _a_generated_object(folder) -> str:
    """One generated stone at 2,000 Gaussians (a kind the tiny run never trains on), as a pool source."""
    from pixie_gs.cli.main import main
    from pixie_gs.dataset.loader import list_objects

    assert main(["generate", str(folder / "stone"), "--count", "1", "--split", "test", "--gaussians", "2000",
                 "--classes", "stones", "-q"]) == 0
    return str(list_objects(folder / "stone", "test")[0])
