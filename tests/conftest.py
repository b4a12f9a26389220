"""Fixtures shared by several test modules."""
from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """Two kinds of objects, a start checkpoint trained one epoch on them; returns (folder, data, start, flags).

    For the fine-tune terms (`--anchor-weight` in test_model.py, `--distill` and `--teacher-pool` in
    test_distill.py): each writes its own outputs, none changes the data or the start checkpoint."""
    from pixie_gs.cli.main import main

    root = tmp_path_factory.mktemp("fine_tune")
    data = root / "data"
    for split, count in (("train", 4), ("val", 2)):
        assert main(["generate", str(data), "--count", str(count), "--split", split, "--gaussians", "400",
                     "--classes", "sport_balls,soda_cans", "-q"]) == 0
    common = ["--device", "cpu", "--resolution", "16", "--base-channels", "4", "--multipliers", "1,2",
              "--batch-size", "2", "--seed", "3", "-q"]
    start = root / "start.pt"
    assert main(["train", str(data), "--out", str(start), "--epochs", "1", *common]) == 0
    return root, data, start, common
