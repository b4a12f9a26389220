"""`pixie annotate DIR OUT --ray local`: 8 assets through a local Ray instance with 2 CPU model actors
give the same bytes as the single-process batch and as the single-file command."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from pixie_gs.cli.main import main

ray = pytest.importorskip("ray", reason="the Ray test needs the [ray] extra: pip install -e '.[ray]'")

from test_batch_annotate import write_asset  # noqa: E402

CLASSES = ("rubber_ducks_toys", "soda_cans", "tree", "sand", "snow_mud", "metal_crates", "flowers", "stones")


def test_ray_batch_of_8_assets_matches_single_process_bytes(tmp_path, capsys):
    lib = tmp_path / "lib"
    lib.mkdir()
    for i, name in enumerate(CLASSES):
        write_asset(lib / f"{i:02d}_{name}.ply", name, 200 + i, 2500)
    local, on_ray = tmp_path / "local", tmp_path / "ray"
    assert main(["annotate", str(lib), str(local), "--pool", "thread", "-q"]) == 0
    single = tmp_path / "single.ply"
    assert main(["annotate", str(lib / "00_rubber_ducks_toys.ply"), str(single), "-q"]) == 0
    capsys.readouterr()
    assert main(["annotate", str(lib), str(on_ray), "--ray", "local", "--workers", "2"]) == 0
    assert "annotated 8, failed 0" in capsys.readouterr().out
    assert not ray.is_initialized()  # the local instance was shut down
    names = sorted(f.name for f in lib.iterdir())
    assert sorted(f.name for f in on_ray.glob("*.ply")) == names
    for n in names:
        assert (on_ray / n).read_bytes() == (local / n).read_bytes(), n
    assert (on_ray / names[0]).read_bytes() == single.read_bytes()
    records = [json.loads(line) for line in (on_ray / "summary.jsonl").read_text().splitlines()]
    assert sorted(Path(r["input"]).name for r in records) == names
    assert all(r["status"] == "ok" and r["gaussians"] > 1000 for r in records)
