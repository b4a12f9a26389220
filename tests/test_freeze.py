"""`pixie train --freeze`: a fine-tune that keeps some network parts at the start's weights."""
from __future__ import annotations

import torch

from pixie_gs.cli.main import main
from pixie_gs.model.unet import DECODER_PARTS, ENCODER_PARTS


def _weights(path):
    return torch.load(path, map_location="cpu", weights_only=False)["state_dict"]


def test_freeze_encoder_keeps_it_bit_identical_and_trains_the_decoder(tiny_run, tmp_path):
    root, data, start, common = tiny_run
    out = tmp_path / "frozen.pt"
    assert main(["train", str(data), "--out", str(out), "--epochs", "2", "--init", str(start),
                 "--freeze", "encoder", "--lr", "1e-2", *common]) == 0
    before, after = _weights(start), _weights(out)
    parts = {name.split(".")[0] for name in before}
    assert parts <= set(ENCODER_PARTS) | set(DECODER_PARTS)  # every part is one or the other
    for name, value in before.items():
        if name.split(".")[0] in ENCODER_PARTS:
            assert torch.equal(after[name], value), name
    moved = [name for name, value in before.items()
             if name.split(".")[0] in DECODER_PARTS and not torch.equal(after[name], value)]
    assert {name.split(".")[0] for name in moved} >= {"up_blocks", "class_head", "physical_head"}
    # --resume with the same parts continues; the state holds the decoder's optimiser state only
    assert main(["train", str(data), "--out", str(out), "--epochs", "3", "--init", str(start),
                 "--freeze", "encoder", "--lr", "1e-2", "--resume", *common]) == 0
    assert all(torch.equal(_weights(out)[n], v) for n, v in before.items() if n.split(".")[0] in ENCODER_PARTS)
    # … and with other parts it is refused in one line, the checkpoint left as it was
    kept = out.read_bytes()
    assert main(["train", str(data), "--out", str(out), "--epochs", "4", "--init", str(start),
                 "--freeze", "stem", "--resume", *common]) == 1
    assert out.read_bytes() == kept


def test_freeze_refusals(tiny_run, tmp_path, capsys):
    root, data, start, common = tiny_run
    out = tmp_path / "x.pt"
    assert main(["train", str(data), "--out", str(out), "--freeze", "encoder", *common]) == 1
    assert "--freeze needs --init" in capsys.readouterr().err
    assert main(["train", str(data), "--out", str(out), "--init", str(start), "--freeze", "encoder,wings",
                 *common]) == 1
    assert "no network part named wings" in capsys.readouterr().err
    assert main(["train", str(data), "--out", str(out), "--init", str(start), "--freeze",
                 ",".join(ENCODER_PARTS + DECODER_PARTS), *common]) == 1
    assert "leaves no parameter to train" in capsys.readouterr().err
    assert not out.exists()
