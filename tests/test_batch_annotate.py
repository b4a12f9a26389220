"""Batch mode of `pixie annotate` (folder / glob / manifest → folder): byte-identical to the single-file
command, resume, shards, a bad file among good ones, the JSONL summary read back with plyfile."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData

from pixie_gs.batch.jobs import (Job, is_batch_input, list_inputs, make_jobs, output_name, parse_shard,
                                 select_shard)
from pixie_gs.cli.main import main
from pixie_gs.errors import InputError
from pixie_gs.materials import MATERIAL_NAMES

CLASSES = ("rubber_ducks_toys", "soda_cans", "tree", "sand")
LABELS = ("material_id", "E", "nu", "density", "part_id")


def write_asset(path: Path, class_name: str, seed: int, count: int) -> None:
    """A generated object (labels stripped, as a capture would be) written as a 3DGS .ply."""
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.splat import write_splat

    cloud, _ = build_object(load_class_table()[class_name], seed, count)
    for name in LABELS:
        cloud.extras.pop(name, None)
    cloud.property_order = [p for p in cloud.property_order if p not in LABELS]
    write_splat(cloud, path)


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> tuple[Path, Path]:
    """(folder of 4 small assets, folder of their single-file `pixie annotate IN OUT` outputs)."""
    root = tmp_path_factory.mktemp("lib")
    lib, ref = root / "lib", root / "ref"
    lib.mkdir()
    ref.mkdir()
    for i, name in enumerate(CLASSES):
        write_asset(lib / f"{i:02d}_{name}.ply", name, 100 + i, 4000)
    for f in sorted(lib.iterdir()):
        assert main(["annotate", str(f), str(ref / f.name), "-q"]) == 0
    return lib, ref


def read_summary(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def sidecar_without_seconds(path: Path) -> dict:
    d = json.loads(path.read_text())
    d.pop("seconds")
    return d


def test_batch_outputs_are_byte_identical_to_single_file_runs(library, tmp_path):
    lib, ref = library
    out = tmp_path / "out"
    assert main(["annotate", str(lib), str(out), "--pool", "thread", "--workers", "2", "-q"]) == 0
    for f in sorted(lib.iterdir()):
        assert (out / f.name).read_bytes() == (ref / f.name).read_bytes(), f.name
        side = f.name.replace(".ply", ".prepare.json")
        assert sidecar_without_seconds(out / side) == sidecar_without_seconds(ref / side)
    records = read_summary(out / "summary.jsonl")
    assert sorted(r["status"] for r in records) == ["ok"] * len(CLASSES)
    for rec in records:  # each summary line agrees with its file, read back by plyfile (not pixie's reader)
        v = PlyData.read(rec["output"])["vertex"].data
        mid, E, conf = np.asarray(v["material_id"]), np.asarray(v["E"], np.float64), np.asarray(v["confidence"])
        assert rec["gaussians"] == len(mid) == PlyData.read(rec["input"])["vertex"].count
        ids, counts = np.unique(mid, return_counts=True)
        assert rec["classes"] == pytest.approx({MATERIAL_NAMES[int(i)]: c / len(mid) for i, c in zip(ids, counts)},
                                               abs=1e-5)
        assert sum(rec["classes"].values()) == pytest.approx(1.0, abs=1e-4)
        for key, q in (("p05", 0.05), ("p50", 0.5), ("p95", 0.95)):
            assert rec["E_pa_quantiles"][key] == pytest.approx(np.quantile(E, q), rel=1e-3)
        assert rec["confidence"]["mean"] == pytest.approx(conf.mean(), abs=1e-4)
        assert rec["seconds"] > 0 and set(rec["step_seconds"]) == {"read_prepare", "model", "write"}


def test_process_pool_gives_the_same_bytes(library, tmp_path):
    lib, ref = library
    out = tmp_path / "out"
    assert main(["annotate", str(lib / "0[01]_*.ply"), str(out), "--pool", "process", "--workers", "2", "-q"]) == 0
    names = sorted(os.listdir(lib))[:2]
    assert sorted(f.name for f in out.glob("*.ply")) == names
    for n in names:
        assert (out / n).read_bytes() == (ref / n).read_bytes(), n


def test_resume_skips_finished_outputs_only(library, tmp_path):
    lib, ref = library
    out = tmp_path / "out"
    assert main(["annotate", str(lib), str(out), "--pool", "thread", "-q"]) == 0
    names = sorted(f.name for f in lib.iterdir())
    stamps = {n: (out / n).stat().st_mtime_ns for n in names}
    (out / names[1]).unlink()  # never written
    (out / names[2].replace(".ply", ".prepare.json")).unlink()  # killed between the .ply and its sidecar
    (out / f".{names[3]}.pixie-tmp-999999999-x.tmp").write_bytes(b"partial")  # a killed writer's temp file
    assert main(["annotate", str(lib), str(out), "--pool", "thread", "-q"]) == 0
    second = read_summary(out / "summary.jsonl")[len(names):]
    status = {Path(r["input"]).name: r["status"] for r in second}
    assert status == {names[0]: "skipped", names[1]: "ok", names[2]: "ok", names[3]: "skipped"}
    assert (out / names[0]).stat().st_mtime_ns == stamps[names[0]]
    for n in names:
        assert (out / n).read_bytes() == (ref / n).read_bytes()
    # --force annotates a finished one again
    assert main(["annotate", str(lib / names[0]).replace(".ply", ".pl[y]"), str(out), "--pool", "thread",
                 "--force", "-q"]) == 0
    assert [r["status"] for r in read_summary(out / "summary.jsonl")[len(names) * 2:]] == ["ok"]
    assert (out / names[0]).stat().st_mtime_ns != stamps[names[0]]


def test_a_bad_file_fails_alone_with_its_error_in_the_summary(library, tmp_path, capsys):
    lib, ref = library
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for name in sorted(os.listdir(lib))[:2]:
        shutil.copy(lib / name, mixed / name)
    good = (mixed / sorted(os.listdir(lib))[0]).read_bytes()
    (mixed / "broken.ply").write_bytes(good[: len(good) // 2])  # truncated: the header promises more
    before = (mixed / "broken.ply").read_bytes()
    out = tmp_path / "out"
    code = main(["annotate", str(mixed), str(out), "--pool", "thread"])
    assert code == 1
    err = capsys.readouterr().err
    assert "1 of 3 asset(s) failed" in err and "broken.ply" in err
    records = {Path(r["input"]).name: r for r in read_summary(out / "summary.jsonl")}
    bad = records.pop("broken.ply")
    assert bad["status"] == "failed" and "broken.ply" in bad["error"] and "\n" not in bad["error"]
    assert not (out / "broken.ply").exists()
    assert (mixed / "broken.ply").read_bytes() == before  # the input is never touched
    assert all(r["status"] == "ok" for r in records.values())
    for name in records:
        assert (out / name).read_bytes() == (ref / name).read_bytes()


def test_shards_split_the_library_and_write_their_own_summaries(library, tmp_path):
    lib, ref = library
    out = tmp_path / "out"
    names = sorted(os.listdir(lib))
    assert main(["annotate", str(lib), str(out), "--shard", "1/2", "--pool", "thread", "-q"]) == 0
    assert sorted(f.name for f in out.glob("*.ply")) == names[1::2]
    env = {"SLURM_ARRAY_TASK_ID": "1", "SLURM_ARRAY_TASK_MIN": "1", "SLURM_ARRAY_TASK_COUNT": "2"}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # shard 0 of 2 from a SLURM array numbered 1..2
    try:
        assert main(["annotate", str(lib), str(out), "--pool", "thread", "-q"]) == 0
    finally:
        for k, v in old.items():
            os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)
    assert sorted(f.name for f in out.glob("*.ply")) == names
    assert len(read_summary(out / "summary.shard-1-of-2.jsonl")) == 2
    assert len(read_summary(out / "summary.shard-0-of-2.jsonl")) == 2
    for n in names:
        assert (out / n).read_bytes() == (ref / n).read_bytes()


def test_glob_and_manifest_inputs(library, tmp_path):
    lib, ref = library
    names = sorted(os.listdir(lib))
    out = tmp_path / "g"
    assert main(["annotate", str(lib / "0[2]_*.ply"), str(out), "--pool", "thread", "-q"]) == 0
    assert sorted(f.name for f in out.glob("*.ply")) == [names[2]]
    manifest = tmp_path / "assets.txt"
    rel = os.path.relpath(lib / names[3], tmp_path)
    manifest.write_text(f"# two assets\n{rel}\n\n{lib / names[1]}\n")
    out = tmp_path / "m"
    assert main(["annotate", str(manifest), str(out), "--pool", "thread", "-q"]) == 0
    assert sorted(f.name for f in out.glob("*.ply")) == [names[1], names[3]]
    assert (out / names[3]).read_bytes() == (ref / names[3]).read_bytes()


def test_batch_input_errors_are_one_line_and_write_nothing(library, tmp_path, capsys):
    lib, _ = library
    assert main(["annotate", str(lib), str(lib)]) == 1  # would overwrite the inputs
    assert "overwrite" in capsys.readouterr().err
    assert main(["annotate", str(tmp_path / "*.ply"), str(tmp_path / "o")]) == 1
    assert "matches no file" in capsys.readouterr().err
    assert main(["annotate", str(lib), str(tmp_path / "o"), "--shard", "2/2"]) == 1
    assert "shard 2 of 2 does not exist" in capsys.readouterr().err
    assert main(["annotate", str(lib), str(tmp_path / "o"), "--rrd", str(tmp_path / "x.rrd")]) == 1
    assert main(["annotate", str(lib), str(tmp_path / "o.ply")]) == 1
    assert "names a splat file" in capsys.readouterr().err
    one = str(lib / sorted(os.listdir(lib))[0])
    assert main(["annotate", one, str(tmp_path / "o.ply"), "--shard", "0/2"]) == 1
    assert "--shard is for batch mode" in capsys.readouterr().err
    twins = tmp_path / "twins"
    twins.mkdir()
    shutil.copy(lib / sorted(os.listdir(lib))[0], twins / "a.ply")
    (twins / "a.splat").write_bytes(b"\0" * 32)
    assert main(["annotate", str(twins), str(tmp_path / "o")]) == 1
    assert "same output" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_job_listing_naming_and_sharding(tmp_path):
    for name in ("b.ply", "a.splat", "c.compressed.ply", "d.spz", "notes.md", ".hidden.ply"):
        (tmp_path / name).write_bytes(b"x")
    files = list_inputs(str(tmp_path))
    assert [f.name for f in files] == ["a.splat", "b.ply", "c.compressed.ply", "d.spz"]
    assert [output_name(f) for f in files] == ["a.ply", "b.ply", "c.ply", "d.ply"]
    jobs = make_jobs(files, tmp_path / "out")
    shards = [select_shard(jobs, i, 3) for i in range(3)]
    assert sorted(j.index for s in shards for j in s) == [0, 1, 2, 3]  # every job in exactly one shard
    assert [j.index for j in shards[1]] == [1]
    assert is_batch_input(str(tmp_path)) and is_batch_input(str(tmp_path / "*.ply"))
    assert is_batch_input("list.txt") and not is_batch_input(str(tmp_path / "b.ply"))
    assert parse_shard("3/4", {}) == (3, 4)
    assert parse_shard(None, {}) == (0, 1)
    assert parse_shard(None, {"SLURM_ARRAY_TASK_ID": "7", "SLURM_ARRAY_TASK_COUNT": "8"}) == (7, 8)
    for bad in ("4/4", "-1/4", "a/b", "1"):
        with pytest.raises(InputError):
            parse_shard(bad, {})
    assert Job(0, "a", "b") == Job(0, "a", "b")


def test_batch_mode_never_imports_warp(library, tmp_path):
    """The GPU box that runs the batch benchmark has torch, numpy, scipy and plyfile but no Warp."""
    lib, _ = library
    code = ("import sys; from pixie_gs.cli.main import main; "
            f"rc = main(['annotate', {str(lib / '00_*.ply')!r}, {str(tmp_path / 'o')!r}, '-q', '--pool', 'thread']); "
            "assert rc == 0, rc; assert 'warp' not in sys.modules, 'warp was imported'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)
    assert (tmp_path / "o" / "00_rubber_ducks_toys.ply").is_file()
