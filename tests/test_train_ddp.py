"""Data-parallel `pixie train` (issue 16) with two gloo processes on the CPU.

What must hold: the two ranks' shares of a global batch are disjoint halves of it; the gradient DDP
averages equals the one-process gradient of the whole batch (also for a last batch shorter than the
world, where one rank joins with weight 0); both ranks end with the same weights, and with the
weights one process reaches on the same data; rank 0 alone writes; `torchrun … pixie train --resume`
continues a run from its saved step.
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from pixie_gs.cli.main import main
from pixie_gs.errors import InputError
from pixie_gs.model.distributed import SINGLE, DistContext, context_from_env, rank_share
from pixie_gs.model.unet import ENCODER_PARTS

TINY_CLI = ["--device", "cpu", "--resolution", "16", "--base-channels", "4", "--multipliers", "1,2", "-q"]
TRAIN_OBJECTS = 5


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """5 train / 2 val generated objects of 400 Gaussians."""
    d = tmp_path_factory.mktemp("ddp") / "data"
    for split, count in (("train", TRAIN_OBJECTS), ("val", 2)):
        assert main(["generate", str(d), "--count", str(count), "--split", split, "--gaussians", "400",
                     "--classes", "sport_balls,soda_cans", "-q"]) == 0
    return d


def tiny_config(**kw):
    from pixie_gs.model.train import TrainConfig

    return TrainConfig(epochs=2, batch_size=4, lr=5e-3, warmup_steps=1, seed=5, augment=True,
                       model={"base_channels": 4, "multipliers": [1, 2]}, features={"resolution": 16}, **kw)


def test_rank_shares_are_disjoint_and_cover_the_batch():
    for world in (2, 3):
        for n in range(1, 8):
            ids = list(range(10, 10 + n))
            shares = [rank_share(ids, DistContext(r, world, r)) for r in range(world)]
            counted = [s for s, counts in shares if counts]
            assert sorted(i for s in counted for i in s) == ids  # disjoint, and together the batch
            assert all(abs(len(s) - len(counted[0])) <= 1 for s in counted)
            for s, counts in shares:
                assert counts or s == ids[:1]  # an empty rank still runs one object, with weight 0
    assert rank_share([3, 1, 2], SINGLE) == ([3, 1, 2], True)


def test_context_from_the_torchrun_environment():
    assert context_from_env({}) == SINGLE and not SINGLE.enabled
    ctx = context_from_env({"WORLD_SIZE": "4", "RANK": "3", "LOCAL_RANK": "1"})
    assert (ctx.rank, ctx.world_size, ctx.local_rank, ctx.enabled, ctx.is_main) == (3, 4, 1, True, False)
    for bad in ({"WORLD_SIZE": "two"}, {"WORLD_SIZE": "2", "RANK": "2"}, {"WORLD_SIZE": "0"}):
        with pytest.raises(InputError):
            context_from_env(bad)


def test_building_several_steps_at_once_gives_the_same_batches(data):
    """step_batches with 1, 2 and 3 steps per build call: the same objects, augmentation draws, grids
    and labels per step (the CUDA default builds ~128 objects per call)."""
    from pixie_gs.model.batch import AugmentConfig, build_batch
    from pixie_gs.model.checkpoint import FeatureSpec
    from pixie_gs.model.data import DeviceStore, load_split
    from pixie_gs.model.step_batches import step_batches

    records, extra = load_split(data, "train")
    store = DeviceStore(records, "cpu")
    spec = FeatureSpec(resolution=16, extra_names=tuple(extra))
    batches = [[3, 1], [0, 4], [2]]
    runs = [list(step_batches(store, batches, spec, AugmentConfig(), 11, SINGLE, k))
            for k in (1, 4, 6)]
    for steps in zip(*runs):
        first = steps[0][1]
        assert len(first.means_unit) == len(steps[0][0])
        for _, other, counts in steps[1:]:
            assert counts
            assert torch.equal(first.occupied, other.occupied) and torch.equal(first.target_class, other.target_class)
            assert torch.allclose(first.inputs, other.inputs, atol=1e-5)
            assert torch.allclose(first.target_physical, other.target_physical, atol=1e-5)
    assert [ids for ids, _, _ in runs[1]] == batches
    plain = build_batch(store, batches[0], spec)  # augmentation did act: the grids differ from unaugmented ones
    assert not torch.equal(plain.occupied, runs[0][0][1].occupied)


def anchored_config(start: Path):
    return tiny_config(init_from=str(start), anchor_weight=50.0)


def distilled_config(out: Path):
    """A fine-tune of ddp.pt held towards anchored.pt's outputs on the sport balls (the cans left to the
    labels), so some ranks' shares have no kept voxels."""
    return tiny_config(init_from=str(out / "ddp.pt"), distill_from=str(out / "anchored.pt"), distill_weight=10.0,
                       distill_skip=["soda_cans"])


def frozen_config(out: Path):
    """A fine-tune of ddp.pt with the encoder frozen: DDP reduces the decoder's gradients only."""
    return tiny_config(init_from=str(out / "ddp.pt"), freeze=["encoder"])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _worker(rank: int, world: int, port: int, data_dir: str, out_dir: str) -> None:
    """One rank: gradients of two global batches under DDP and in one process, then train()."""
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world),
                      LOCAL_RANK=str(rank))
    torch.set_num_threads(1)
    from torch.nn.parallel import DistributedDataParallel

    from pixie_gs.errors import InputError
    from pixie_gs.model import distributed
    from pixie_gs.model import step_batches as steps_mod
    from pixie_gs.model import train as train_mod
    from pixie_gs.model.checkpoint import FeatureSpec
    from pixie_gs.model.data import DeviceStore, load_split
    from pixie_gs.model.predict import grid_channel_names
    from pixie_gs.model.step_batches import step_batches
    from pixie_gs.model.unet import MaterialUNet, ModelConfig
    from pixie_gs.progress import set_quiet

    set_quiet(True)
    out = Path(out_dir)
    ctx = distributed.context_from_env()
    device = distributed.join(ctx, "cpu")
    try:
        records, extra = load_split(data_dir, "train")
        store = DeviceStore(records, device)
        spec = FeatureSpec(resolution=16, extra_names=tuple(extra))
        names = grid_channel_names(extra)
        grads = {}
        for ids in ([4, 0, 2], [1]):  # shares of 2 + 1 objects; then 1 + 0 (rank 1 joins with weight 0)
            torch.manual_seed(0)
            net = MaterialUNet(ModelConfig(input_channels=names, base_channels=4, multipliers=[1, 2]))
            torch.manual_seed(0)
            alone = MaterialUNet(ModelConfig(input_channels=names, base_channels=4, multipliers=[1, 2]))
            ddp = DistributedDataParallel(net)  # held: a collected wrapper stops averaging the gradients
            [(_, share, counts)] = step_batches(store, [ids], spec, None, None, ctx)
            loss, value, parts = train_mod.batch_loss(ddp, share, counts, names, names, 1.0, False, ctx)
            loss.backward()
            [(_, whole, _)] = step_batches(store, [ids], spec, None, None, SINGLE)
            loss1, value1, parts1 = train_mod.batch_loss(alone, whole, True, names, names, 1.0, False, SINGLE)
            loss1.backward()
            grads[str(ids)] = {"ddp": {k: p.grad for k, p in net.named_parameters()},
                               "one": {k: p.grad for k, p in alone.named_parameters()},
                               "value": (value, value1), "parts": (parts, parts1)}
        # the real training loop, recording which objects each call built and who saved a checkpoint
        built, saved, nets = [], [], []
        real_build, real_save, real_net = steps_mod.build_batch, train_mod.save_checkpoint, train_mod.MaterialUNet

        def build(store, ids, *a, **k):
            built.append((len(store), list(ids)))
            return real_build(store, ids, *a, **k)

        class Recorded(real_net):
            def __init__(self, *a, **k):
                super().__init__(*a, **k)
                nets.append(self)

        train_mod.build_batch = steps_mod.build_batch = build  # validation, training
        train_mod.save_checkpoint = lambda *a, **k: (saved.append(rank), real_save(*a, **k))[1]
        train_mod.MaterialUNet = Recorded
        # 4 objects per build: both steps of an epoch (shares of 2 and 1 objects) in one call
        train_mod.train(data_dir, out / "ddp.pt", tiny_config(objects_per_build=4), device, dist=ctx)
        weights, built_main = nets[0].state_dict(), list(built)
        # a time budget spent before the first step: rank 0's clock stops every rank, none hangs
        try:
            train_mod.train(data_dir, out / "budget.pt", tiny_config(time_budget_s=1e-9), device, dist=ctx)
            budget = "finished"
        except InputError as exc:
            budget = str(exc)
        # a fine-tune of that run's weights with the L2-SP anchor: every rank adds the same penalty
        train_mod.train(data_dir, out / "anchored.pt", anchored_config(out / "ddp.pt"), device, dist=ctx)
        # distillation: each rank's term scaled by its share of the kept voxels
        train_mod.train(data_dir, out / "distilled.pt", distilled_config(out), device, dist=ctx)
        # the encoder frozen (`--freeze encoder`)
        train_mod.train(data_dir, out / "frozen.pt", frozen_config(out), device, dist=ctx)
        torch.save({"grads": grads, "built": built_main, "saved": saved, "weights": weights, "budget": budget},
                   out / f"rank{rank}.pt")
    finally:
        distributed.leave(ctx)


@pytest.fixture(scope="module")
def two_ranks(data, tmp_path_factory):
    """Run _worker on 2 gloo processes; returns (output folder, the ranks' results)."""
    import torch.multiprocessing as mp

    out = tmp_path_factory.mktemp("ddp_out")
    procs = mp.spawn(_worker, args=(2, _free_port(), str(data), str(out)), nprocs=2, join=False)
    deadline = time.monotonic() + 600
    while not procs.join(timeout=2):  # raises when a rank failed
        if time.monotonic() > deadline:
            for p in procs.processes:
                p.kill()
            pytest.fail("the 2-process run did not finish in 600 s (a rank waiting in a collective?)")
    return out, [torch.load(out / f"rank{r}.pt", weights_only=False) for r in range(2)]


def test_two_process_gradient_equals_one_process_gradient(two_ranks):
    _, ranks = two_ranks
    for batch in ("[4, 0, 2]", "[1]"):
        for r in ranks:
            g = r["grads"][batch]
            assert g["value"][0] == pytest.approx(g["value"][1], rel=1e-5)
            assert g["parts"][0] == pytest.approx(g["parts"][1], rel=1e-5)
            scale = max(float(v.abs().max()) for v in g["one"].values())
            assert scale > 1e-3  # a real gradient, not zeros on both sides
            for k, want in g["one"].items():
                assert torch.allclose(g["ddp"][k], want, rtol=1e-4, atol=1e-6 * scale), (batch, k)


def test_ranks_see_disjoint_halves_and_only_rank_0_writes(two_ranks):
    out, ranks = two_ranks
    train_calls = [[ids for n, ids in r["built"] if n == TRAIN_OBJECTS] for r in ranks]
    val_calls = [[ids for n, ids in r["built"] if n == 2] for r in ranks]
    # per epoch one build call per rank for both steps (a batch of 4, then a batch of 1): its share of
    # step 1 (2 objects), then of step 2
    assert [[len(ids) for ids in c] for c in train_calls] == [[3, 3], [3, 3]]
    for epoch in range(2):
        (*full0, tail0), (*full1, tail1) = train_calls[0][epoch], train_calls[1][epoch]
        assert not set(full0) & set(full1)
        assert sorted(full0 + full1 + [tail0]) == list(range(TRAIN_OBJECTS))  # the epoch covers every object once
        assert tail1 == tail0  # rank 1 had nothing in the last batch: it ran rank 0's object with weight 0
    assert val_calls == [[[0]] * 2, [[1]] * 2]  # the val loss is split too, one object each per epoch
    assert ranks[0]["saved"] and not ranks[1]["saved"]
    assert ranks[0]["budget"] == ranks[1]["budget"] and "before a single epoch finished" in ranks[0]["budget"]
    state = torch.load(str(out / "ddp.pt") + ".state.pt", weights_only=True)
    assert state["step"] == 4 and [h["epoch"] for h in json.loads(state["history_json"])] == [1, 2]


def test_ranks_agree_and_match_one_process_training(two_ranks, data, tmp_path):
    """Both ranks hold bit-identical weights, and one process on the same data lands on the same
    network: the same losses every epoch and the same outputs, augmentation on (each object's draws
    belong to it and the epoch, not to the rank that builds it). (Compared through outputs: a conv bias
    that feeds a GroupNorm has a zero gradient up to float noise, which AdamW turns into ±lr steps
    that differ between runs without changing the network's function.)"""
    from pixie_gs.model.batch import build_batch
    from pixie_gs.model.checkpoint import load_checkpoint
    from pixie_gs.model.data import DeviceStore, load_split
    from pixie_gs.model.predict import grid_channel_names, select_inputs
    from pixie_gs.model.train import train
    from pixie_gs.progress import set_quiet

    out, ranks = two_ranks
    w0, w1 = ranks[0]["weights"], ranks[1]["weights"]
    assert all(torch.equal(w0[k], w1[k]) for k in w0)  # DDP keeps the ranks bit-identical
    set_quiet(True)
    try:
        meta = train(data, tmp_path / "one.pt", tiny_config(), "cpu")
    finally:
        set_quiet(False)
    ddp_history = json.loads(torch.load(str(out / "ddp.pt") + ".state.pt", weights_only=True)["history_json"])
    assert meta["history"][0]["val_loss"] > meta["history"][1]["val_loss"]  # it learned something
    for a, b in zip(meta["history"], ddp_history, strict=True):
        for key in ("train_loss", "train_ce", "val_loss", "val_accuracy", "val_mse_avg"):
            assert a[key] == pytest.approx(b[key], rel=1e-4, abs=1e-5), key
        assert (a["processes"], b["processes"]) == (1, 2)
    loaded = load_checkpoint(tmp_path / "one.pt")
    net = loaded.model.float().eval()
    records, extra = load_split(data, "val", list(loaded.features.extra_names))
    batch = build_batch(DeviceStore(records, "cpu"), [0, 1], loaded.features)
    x = select_inputs(batch.inputs, grid_channel_names(extra), loaded.config.input_channels)
    one = torch.load(str(tmp_path / "one.pt") + ".state.pt", weights_only=True)["model"]
    with torch.no_grad():
        net.load_state_dict(one)
        want = torch.cat([t.flatten() for t in net(x)])
        net.load_state_dict(w0)
        got = torch.cat([t.flatten() for t in net(x)])
    assert float((got - want).abs().max()) < 1e-4 * float(want.abs().max())


def test_torchrun_cli_resumes_a_preempted_run(data, tmp_path):
    """Epoch 1 by one process (as if the job was preempted after it), then
    `torchrun --nproc_per_node 2 -m pixie_gs.cli.main train … --resume` continues to epoch 2 from the
    saved step: the state does not depend on the process count (global batches of --batch-size)."""
    ckpt = tmp_path / "m.pt"
    args = ["train", str(data), "--out", str(ckpt), "--batch-size", "2", *TINY_CLI]
    assert main(args + ["--epochs", "1"]) == 0
    state = torch.load(str(ckpt) + ".state.pt", weights_only=True)
    first = json.loads(state["history_json"])
    assert state["epoch"] == 1 and state["step"] == 3  # 5 objects in global batches of 2
    repo = str(Path(__file__).resolve().parents[1])  # kept in front of any PYTHONPATH the machine needs
    env = {**os.environ, "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join(filter(None, [repo, os.environ.get("PYTHONPATH")]))}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           "-m", "pixie_gs.cli.main", *args, "--epochs", "2", "--resume", "--log-json", str(tmp_path / "log.json")]
    run = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.count("checkpoint ") == 1  # rank 0 alone reports
    state2 = torch.load(str(ckpt) + ".state.pt", weights_only=True)
    history = json.loads(state2["history_json"])
    assert state2["step"] == 6 and [h["epoch"] for h in history] == [1, 2] and history[0] == first[0]
    assert [h["processes"] for h in history] == [1, 2] and history[1]["train_objects_per_s"] > 0
    log = json.loads((tmp_path / "log.json").read_text())["meta"]["history"]
    assert log == history


@pytest.mark.parametrize("name,logged", [("anchored", "drift_sq"), ("distilled", "train_distill"),
                                         ("frozen", "drift_sq")])
def test_fine_tune_terms_match_one_process(two_ranks, data, tmp_path, name, logged):
    """`--anchor-weight` (each rank adds the same Σ (θ − θ_start)²), `--distill` (each rank's term scaled by
    its share of the kept voxels) and `--freeze encoder` (the frozen parts outside DDP's reduction) under DDP:
    the run matches one process doing the same fine-tune epoch by epoch, the logged term included."""
    from pixie_gs.model.train import train
    from pixie_gs.progress import set_quiet

    out, _ = two_ranks
    config = {"anchored": anchored_config(out / "ddp.pt"), "distilled": distilled_config(out),
              "frozen": frozen_config(out)}[name]
    set_quiet(True)
    try:
        meta = train(data, tmp_path / "one.pt", config, "cpu")
    finally:
        set_quiet(False)
    ddp_history = json.loads(torch.load(str(out / f"{name}.pt") + ".state.pt", weights_only=True)["history_json"])
    assert all(row[logged] > 0 for row in ddp_history)
    for a, b in zip(meta["history"], ddp_history, strict=True):
        for key in ("train_loss", "val_loss", logged):
            assert a[key] == pytest.approx(b[key], rel=1e-3, abs=1e-6), key
    if name == "frozen":  # the ranks kept the encoder exactly as ddp.pt had it
        start, done = (torch.load(out / f, weights_only=False)["state_dict"] for f in ("ddp.pt", "frozen.pt"))
        assert all(torch.equal(done[k], v) for k, v in start.items() if k.split(".")[0] in ENCODER_PARTS)
