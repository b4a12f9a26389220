"""No silent wrong answer, no lost data (issue 15): every numeric field validated on read,
checkpoints checked against a schema, resource bounds before allocation, staged outputs, signals.

Bad files are written with plyfile / json / torch directly (not through pixie-gs, which refuses to
write them), and every command runs in-process through `pixie_gs.cli.main.main` as a user runs it.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fuzz_corpus import default_sigint, vertex_table, write_ply

from pixie_gs.cli.main import main
from pixie_gs.errors import InputError
from pixie_gs.splat import SplatCloud, read_splat, read_splat_valid

N = 200


def run_cli(args: list[str], capsys) -> tuple[int, str]:
    rc = main([str(a) for a in args])
    err = capsys.readouterr().err
    return rc, err


def one_error_line(err: str) -> str:
    lines = [line for line in err.strip().splitlines() if line and not line.startswith("[pixie]")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


# ------------------------------------------------------------------------- every numeric field
BAD_VALUES = [
    ("opacity", 5, np.nan, "opacity"),
    ("f_dc_1", 7, np.inf, "f_dc"),
    ("f_rest_4", 11, np.nan, "f_rest"),
    ("feature_7", 3, -np.inf, "feature_7"),
    ("x", 9, 1e-40, "position"),  # subnormal: made NaN in the feature grid before
    ("scale_0", 2, 69.0, "scale"),  # a 1e30 scale: exp(2·69) overflows float32
    ("rot_2", 4, np.nan, "rotation"),
]


@pytest.mark.parametrize("prop,index,value,word", BAD_VALUES)
def test_one_bad_value_is_a_one_line_error_naming_property_count_and_index(tmp_path, capsys, prop, index, value, word):
    t = vertex_table()
    t[prop][index] = value
    path = write_ply(tmp_path / "bad.ply", t)
    with pytest.raises(InputError) as info:
        read_splat(path)
    msg = str(info.value)
    assert str(path) in msg and word in msg and f"1 of {N} Gaussians" in msg and f"vertex {index}" in msg
    assert "\n" not in msg
    before = path.read_bytes()
    rc, err = run_cli(["info", path], capsys)
    assert rc == 1 and word in one_error_line(err)
    rc, err = run_cli(["annotate", path, tmp_path / "out.ply", "--device", "cpu", "-q"], capsys)
    assert rc == 1 and word in one_error_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.ply"] and path.read_bytes() == before


@pytest.mark.parametrize("prop,value,word", [("E", -5.0, "E"), ("nu", 0.5, "nu"), ("density", np.nan, "density"),
                                              ("material_id", 42, "material_id"), ("E", np.inf, "E")])
def test_material_attributes_are_checked(tmp_path, prop, value, word):
    t = vertex_table(materials=True)
    t[prop][17] = value
    with pytest.raises(InputError, match=word) as info:
        read_splat(write_ply(tmp_path / "m.ply", t))
    assert "vertex 17" in str(info.value)


def test_drop_invalid_removes_bad_gaussians_and_says_how_many(tmp_path, capsys):
    t = vertex_table()
    t["opacity"][[3, 50]] = np.nan
    t["f_rest_0"][50] = np.inf  # the same Gaussian twice: counted once
    t["scale_1"][120] = 1e30
    path = write_ply(tmp_path / "bad.ply", t)
    cloud = read_splat_valid(path, drop_invalid=True)
    assert "dropped 3 of 200 Gaussians" in capsys.readouterr().err
    assert len(cloud) == N - 3
    np.testing.assert_array_equal(cloud.means[:, 0], np.delete(t["x"], [3, 50, 120]))
    rc = main(["annotate", str(path), str(tmp_path / "out.ply"), "--device", "cpu", "-q", "--drop-invalid"])
    assert rc == 0
    out = read_splat(tmp_path / "out.ply")
    assert len(out) == N - 3 and np.isfinite(out.get("E")).all() and np.isfinite(out.get("nu")).all()
    assert "dropped 3 of 200" in capsys.readouterr().err
    rc, out_text = main(["info", str(path), "--drop-invalid", "--json"]), capsys.readouterr().out
    assert rc == 0 and json.loads(out_text)["count"] == N - 3


def test_all_invalid_is_still_an_error(tmp_path):
    t = vertex_table(n=5)
    t["opacity"][:] = np.nan
    with pytest.raises(InputError, match="every one of its 5"):
        read_splat_valid(write_ply(tmp_path / "all.ply", t), drop_invalid=True)


def test_valid_cloud_with_extreme_but_sane_values_passes(tmp_path):
    t = vertex_table()
    t["x"][0] = 1e6  # a far-away Gaussian in a metre-unit scene
    t["scale_0"][1] = -30.0  # tiny, but σ² is a normal float32
    t["opacity"][2] = -80.0
    assert len(read_splat(write_ply(tmp_path / "ok.ply", t))) == N


def test_a_valid_splat_with_one_extreme_needle_annotates_to_finite_materials(tmp_path, capsys):
    """One Gaussian σ = (330 m, 18 mm, 18 mm) in a 1 m object (valid: |log σ| ≤ 40): its float32 covariance,
    turned to the found up, is not positive definite, and annotate ended with "E is not finite" (exit 3) on a
    mutated .spz found by fuzzing (stop 53). The field now keeps each Gaussian's weight within its α."""
    t = vertex_table(300, materials=False, extras=False)
    t["scale_0"][0], t["scale_1"][0], t["scale_2"][0] = 5.8, -4.0, -4.0
    src, out = write_ply(tmp_path / "needle.ply", t), tmp_path / "out.ply"
    code, err = run_cli(["annotate", str(src), str(out), "--device", "cpu", "-q"], capsys)
    assert code == 0, err
    assert all(np.isfinite(a).all() for a in read_splat(out).get_materials())


# ------------------------------------------------------------------------- checkpoints
def _payload():
    import torch

    from pixie_gs.model.checkpoint import DEFAULT_CHECKPOINT

    return torch.load(DEFAULT_CHECKPOINT, map_location="cpu", weights_only=True)


def _damage(kind: str):
    import torch

    p = _payload()
    if kind == "nan weight":
        key = next(k for k, v in p["state_dict"].items() if v.is_floating_point())
        p["state_dict"][key] = p["state_dict"][key].clone()
        p["state_dict"][key].view(-1)[0] = float("nan")
    elif kind.startswith("missing "):
        del p[kind.split()[1]]
    elif kind == "negative channels":
        p["config"]["base_channels"] = -4
    elif kind == "negative context width":
        p["config"]["context_width"] = -1
    elif kind == "context width without its weights":
        p["config"]["context_width"] = 64
    elif kind == "resolution 0":
        p["features"]["resolution"] = 0
    elif kind == "resolution 4096":
        p["features"]["resolution"] = 4096
    elif kind == "channels as text":
        p["config"]["projector_hidden"] = "32"
    elif kind == "features as list":
        p["features"] = [64]
    elif kind == "huge width":
        p["config"]["base_channels"] = 1024
        p["config"]["multipliers"] = [1, 64]
    elif kind == "weights not tensors":
        p["state_dict"] = {"w": [1, 2, 3]}
    elif kind == "inf weight":
        key = next(k for k, v in p["state_dict"].items() if v.is_floating_point())
        p["state_dict"][key] = torch.full_like(p["state_dict"][key], float("inf"))
    return p


@pytest.mark.parametrize("kind", ["nan weight", "inf weight", "missing config", "missing features",
                                  "missing state_dict", "negative channels", "negative context width",
                                  "context width without its weights", "resolution 0", "resolution 4096",
                                  "channels as text", "features as list", "huge width", "weights not tensors"])
def test_damaged_checkpoint_payloads_are_refused_in_one_line(tmp_path, capsys, kind):
    import torch

    ckpt = tmp_path / "bad.pt"
    torch.save(_damage(kind), ckpt)
    splat = write_ply(tmp_path / "s.ply", vertex_table(n=50))
    rc, err = run_cli(["annotate", splat, tmp_path / "o.ply", "--checkpoint", ckpt, "--device", "cpu", "-q"], capsys)
    line = one_error_line(err)
    assert rc == 1 and str(ckpt) in line, line
    assert not (tmp_path / "o.ply").exists()
    if kind == "nan weight":
        assert "NaN" in line
        rc, err = run_cli(["evaluate", ckpt, tmp_path / "no_data", "--device", "cpu"], capsys)
        assert rc == 1 and "NaN" in one_error_line(err)


def test_a_pickled_python_object_as_checkpoint_is_one_line_without_torch_warnings(tmp_path, capsys):
    """A pickle of arbitrary Python objects named as the checkpoint: one line saying why it is not loaded, and
    none of torch's own warnings about the file (stop 54: a UserWarning about the pickle protocol and a
    message cut mid-sentence came before)."""
    import pickle
    import warnings

    ckpt = tmp_path / "pickled.pt"
    ckpt.write_bytes(pickle.dumps({"format": "x", "call": os.system.__name__}, protocol=4))
    splat = write_ply(tmp_path / "s.ply", vertex_table(n=50))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc, err = run_cli(["annotate", splat, tmp_path / "o.ply", "--checkpoint", ckpt, "--device", "cpu", "-q"],
                          capsys)
    line = one_error_line(err)
    assert rc == 1 and str(ckpt) in line and "could run code" in line, line
    assert [str(w.message)[:80] for w in caught] == []
    assert not (tmp_path / "o.ply").exists()


def test_a_compressed_ply_with_an_infinite_chunk_bound_is_one_line_without_numpy_warnings(tmp_path, capsys):
    """A compressed PLY whose first chunk's min_x is inf decodes NaN positions: `pixie info` refuses it in one
    line, and numpy's "invalid value encountered" warning from the decode is not printed beside it (stop 54)."""
    import warnings

    from fuzz_corpus import valid_splat_bytes
    from plyfile import PlyData

    source = tmp_path / "ok.compressed.ply"
    source.write_bytes(valid_splat_bytes("compressed.ply"))
    ply = PlyData.read(str(source))
    ply["chunk"].data["min_x"][0] = np.inf
    bad = tmp_path / "inf_chunk.compressed.ply"
    ply.write(str(bad))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc, err = run_cli(["info", bad], capsys)
    line = one_error_line(err)
    assert rc == 1 and str(bad) in line and "non-finite position" in line, line
    assert [str(w.message)[:80] for w in caught] == []


def _overflowing_checkpoint(tmp_path: Path) -> Path:
    """A checkpoint with finite weights scaled by 1e38: its predictions overflow to NaN. (The output norm's
    scale, which feeds both heads: a layer followed by a GroupNorm is normalised back to finite values
    when the statistics are taken exactly.)"""
    import torch

    p = _payload()
    key = "out_norm.0.weight"
    p["state_dict"][key] = p["state_dict"][key] * 1e38
    ckpt = tmp_path / "overflow.pt"
    torch.save(p, ckpt)
    return ckpt


def test_finite_weights_that_overflow_give_exit_3_and_no_file(tmp_path, capsys):
    """A checkpoint whose (finite) weights overflow to NaN materials: a failed computation, not a file."""
    ckpt = _overflowing_checkpoint(tmp_path)
    splat = write_ply(tmp_path / "s.ply", vertex_table(n=80))
    rc, err = run_cli(["annotate", splat, tmp_path / "o.ply", "--checkpoint", ckpt, "--device", "cpu", "-q"], capsys)
    assert rc == 3 and "not finite" in one_error_line(err)
    assert not (tmp_path / "o.ply").exists()


def test_evaluate_with_nan_metrics_is_exit_3_and_writes_no_json(tmp_path, capsys):
    """`evaluate` used to report success with NaN metrics; now a failed computation, no --json file."""
    ckpt = _overflowing_checkpoint(tmp_path)
    assert main(["generate", str(tmp_path / "data"), "--count", "2", "--split", "test", "--gaussians", "200", "-q"]) == 0
    capsys.readouterr()
    rc, err = run_cli(["evaluate", ckpt, tmp_path / "data", "--device", "cpu", "--json", tmp_path / "m.json", "-q"],
                      capsys)
    assert rc == 3 and "not finite" in one_error_line(err)
    assert not (tmp_path / "m.json").exists()


# ------------------------------------------------------------------------- bounds before allocation
def _annotated(tmp_path: Path, n: int = 60) -> Path:
    return write_ply(tmp_path / "in.ply", vertex_table(n=n, materials=True))


def _scene(tmp_path: Path, name: str = "scene.json", **overrides) -> Path:
    d = {"up": "z", "object": {"size_m": 0.3, "position": [0.0, 0.0, 0.05]}, "domain": {"size_m": 1.0, "grid": 16}}
    d.update(overrides)
    path = tmp_path / name
    path.write_text(json.dumps(d))
    return path


@pytest.mark.parametrize("content,word", [
    (b'{"up": "\xff\xfe"}', "UTF-8"),
    (b"[" * 200_000 + b"]" * 200_000, "nested"),
    (b'{"damping": 1' + b"0" * 400 + b"}", "damping"),
    (b'{"damping": 1' + b"0" * 5000 + b"}", "JSON"),
    (b'{"domain": {"size_m": 1e300}}', "domain.size_m"),
    (b'{"domain": {"grid": 100000}}', "domain.grid"),
    (b'{"fixed": [{"part_ids": [1' + b"0" * 300 + b"]}]}", "part_ids"),
])
def test_hostile_scene_files_are_one_line_errors(tmp_path, capsys, content, word):
    sc = tmp_path / "scene.json"
    sc.write_bytes(content)
    ply = _annotated(tmp_path)
    rc, err = run_cli(["simulate", ply, "--out", tmp_path / "o", "--scene", sc, "--device", "cpu", "-q"], capsys)
    line = one_error_line(err)
    assert rc == 1 and word in line and str(sc) in line and len(line) < 400
    assert not (tmp_path / "o").exists()


def test_grid_that_cannot_fit_in_memory_states_the_figure(tmp_path):
    from pixie_gs.sim.scene import Scene

    with pytest.raises(InputError, match=r"needs about [\d.]+ TB of memory"):
        Scene.from_dict({"domain": {"grid": 4000}})


@pytest.mark.parametrize("flags,word", [(["--frames", "1000000000"], "of disk"), (["--fps", "1e-300"], "--fps"),
                                        (["--fps", "inf"], "--fps")])
def test_absurd_frames_or_fps_refused_before_work(tmp_path, capsys, flags, word):
    ply, sc = _annotated(tmp_path), _scene(tmp_path)
    t0 = time.perf_counter()
    rc, err = run_cli(["simulate", ply, "--out", tmp_path / "o", "--scene", sc, "--device", "cpu", "-q", *flags], capsys)
    assert rc == 1 and word in one_error_line(err)
    assert time.perf_counter() - t0 < 30
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply", "scene.json"]


def test_fifo_input_is_refused_without_hanging(tmp_path, capsys):
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    rc, err = run_cli(["info", fifo], capsys)
    assert rc == 1 and "not a regular file" in one_error_line(err)


def test_unwritable_output_is_one_line_naming_the_path(tmp_path, capsys):
    if not Path("/proc/self").is_dir():
        pytest.skip("needs /proc (a read-only file system every Linux has)")
    ply = write_ply(tmp_path / "s.ply", vertex_table(n=50))
    rc, err = run_cli(["annotate", ply, "/proc/pixie_out.ply", "--device", "cpu", "-q"], capsys)
    line = one_error_line(err)
    assert rc == 1 and "/proc" in line


def test_garbage_mesh_does_not_blame_a_missing_module(tmp_path, capsys, monkeypatch):
    """trimesh reaches for charset_normalizer on non-UTF-8 text; without it the user saw 'No module named'."""
    monkeypatch.setitem(sys.modules, "charset_normalizer", None)  # as on an install without it
    mesh = tmp_path / "junk.obj"
    mesh.write_bytes(b"v 1 2 3\nv 1 \xff 3\nv 0 0 1\nf 1 2 3\n")
    rc, err = run_cli(["convert", mesh, tmp_path / "o.ply"], capsys)
    line = one_error_line(err)
    assert rc == 1 and "junk.obj" in line
    assert "charset_normalizer" not in line and "module" not in line.lower()  # an install detail, not the problem


# ------------------------------------------------------------------------- dataset index and tables
def _dataset(tmp_path: Path, index: bytes) -> Path:
    split = tmp_path / "data" / "test"
    split.mkdir(parents=True)
    (split / "index.json").write_bytes(index)
    return tmp_path / "data"


@pytest.mark.parametrize("index,word", [
    (b'{"objects": [1, 2]}', "objects[0]"),
    (b'{"objects": 7}', "objects"),
    (b'\xff\xfe{"objects": []}', "UTF-8"),
    (b'{"objects": [{"file": "/etc/passwd"}]}', "inside the dataset folder"),
    (b'{"objects": [{"file": "../../secret.ply"}]}', "inside the dataset folder"),
    (b'{"objects": [{"file": 12}]}', "objects[0]"),
])
def test_bad_dataset_index_is_one_line_and_confined(tmp_path, capsys, index, word):
    from pixie_gs.dataset.loader import list_objects

    data = _dataset(tmp_path, index)
    with pytest.raises(InputError, match=word.replace("[", r"\[").replace("]", r"\]")):
        list_objects(data, "test")
    rc, err = run_cli(["evaluate", "default", data, "--device", "cpu"], capsys)
    assert rc == 1 and "index.json" in one_error_line(err)


def test_symlink_escaping_the_dataset_is_refused(tmp_path):
    from pixie_gs.dataset.loader import list_objects

    data = _dataset(tmp_path, b'{"objects": [{"file": "link.ply"}]}')
    (data / "test" / "link.ply").symlink_to("/etc/passwd")
    with pytest.raises(InputError, match="outside the dataset folder"):
        list_objects(data, "test")


@pytest.mark.parametrize("table", [
    {"classes": {"a": {"recipe": "box", "parts": {"p": "jelly"}}}},
    {"classes": {"a": {"recipe": "box", "parts": {"p": {"material": "jelly", "E": 1e4, "nu": 0.3,
                                                           "density": 100, "presence": "often"}}}}},
    {"classes": {"a": {"recipe": "box", "parts": {"p": {"material": "jelly", "E": 1e4, "nu": 0.3,
                                                           "density": 100}}, "constraints": 5}}},
    {"classes": {"a": {"recipe": "box", "parts": {"p": {"material": "jelly", "E": 1e4, "nu": 0.3,
                                                           "density": 100}}}}, "widen": {"E_rel": "x"}},
])
def test_class_tables_with_wrong_types_are_one_line(tmp_path, capsys, table):
    path = tmp_path / "table.json"
    path.write_text(json.dumps(table))
    rc, err = run_cli(["generate", tmp_path / "gen", "--count", "1", "--table", path], capsys)
    assert rc == 1 and "table.json" in one_error_line(err)
    assert not (tmp_path / "gen").exists()


# ------------------------------------------------------------------------- staged simulate output
def _simulate(ply: Path, out: Path, sc: Path, frames: int = 3, *extra: str) -> list[str]:
    return ["simulate", str(ply), "--out", str(out), "--scene", str(sc), "--frames", str(frames),
            "--device", "cpu", "-q", *extra]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_input_inside_out_named_like_a_frame_is_never_touched(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    ply = write_ply(out / "frame_00000.ply", vertex_table(n=60, materials=True))
    before = _snapshot(out)
    rc, err = run_cli(_simulate(ply, out, _scene(tmp_path), 3, "--force"), capsys)
    assert rc == 1 and "holds the input" in one_error_line(err)
    assert _snapshot(out) == before


def test_failed_forced_run_keeps_the_old_output_whole(tmp_path, capsys):
    ply, sc, out = _annotated(tmp_path), _scene(tmp_path), tmp_path / "o"
    assert main(_simulate(ply, out, sc, 3)) == 0
    (out / "notes.txt").write_text("mine")
    old = _snapshot(out)
    diverge = _scene(tmp_path, "diverge.json", impulses=[{"time_s": 0.0, "velocity_change": [300.0, 0.0, 0.0]}],
                     solver={"max_substeps_per_frame": 1})
    rc, err = run_cli(_simulate(ply, out, diverge, 5, "--force"), capsys)
    assert rc == 3 and "diverged" in one_error_line(err)
    assert _snapshot(out) == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diverge.json", "in.ply", "o", "scene.json"]  # no staging left
    # a good forced run replaces the frames, keeps the user's file, and leaves no staging folder
    assert main(_simulate(ply, out, sc, 2, "--force")) == 0
    new = _snapshot(out)
    assert sorted(new) == ["frame_00000.ply", "frame_00001.ply", "notes.txt", "preview.png", "tracks.npz"]
    assert new["notes.txt"] == b"mine" and np.load(out / "tracks.npz")["x"].shape[0] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diverge.json", "in.ply", "o", "scene.json"]


def _start_simulate(tmp_path: Path, ply: Path, out: Path, sc: Path, frames: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pixie_gs", *_simulate(ply, out, sc, frames, "--force")],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=default_sigint)


def _wait_for_staging(tmp_path: Path, proc: subprocess.Popen, frames: int = 2, timeout_s: float = 60) -> None:
    """Wait until the run has written `frames` staged frames (so the kill lands mid-run)."""
    t0 = time.time()
    while time.time() - t0 < timeout_s and proc.poll() is None:
        staged = [p for p in tmp_path.iterdir() if ".pixie-staging-" in p.name]
        if staged and len(list(staged[0].glob("frame_*.ply"))) >= frames:
            return
        time.sleep(0.05)
    proc.kill()
    pytest.fail(f"simulate never got going: {proc.poll()} {proc.stderr.read() if proc.poll() is not None else ''}")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL])
def test_signal_mid_run_keeps_the_old_output_whole(tmp_path, sig):
    ply, sc, out = _annotated(tmp_path, n=200), _scene(tmp_path), tmp_path / "o"
    assert main(_simulate(ply, out, sc, 2)) == 0
    old = _snapshot(out)
    proc = _start_simulate(tmp_path, ply, out, sc, 400)
    _wait_for_staging(tmp_path, proc)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert _snapshot(out) == old
    assert "Traceback" not in err
    leftovers = sorted(p.name for p in tmp_path.iterdir() if p.name not in ("in.ply", "o", "scene.json"))
    if sig == signal.SIGKILL:
        assert proc.returncode == -signal.SIGKILL and len(leftovers) == 1  # the dead run's staging folder
        assert main(_simulate(ply, out, sc, 2, "--force")) == 0  # the next run clears it
        leftovers = sorted(p.name for p in tmp_path.iterdir() if p.name not in ("in.ply", "o", "scene.json"))
    else:
        assert proc.returncode == (143 if sig == signal.SIGTERM else 130), err
        assert len([line for line in err.splitlines() if line.strip()]) == 1, err
    assert leftovers == []


_SIGNAL_IN_A_FINALIZER = """
import os, signal, sys
from pixie_gs.cli.main import main
from pixie_gs.sim import frames

class SignalInFinalizer:
    def __del__(self):  # Python runs the handler here, and drops what a finalizer raises
        os.kill(os.getpid(), int(sys.argv[1]))

write = frames.FrameWriter.write
def write_then_signal(self, state):
    path = write(self, state)
    if state.index == 2:
        SignalInFinalizer()  # freed at once, as warp frees its arrays dozens of times a frame
    return path

frames.FrameWriter.write = write_then_signal
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_that_lands_in_a_finalizer_still_stops_the_run(tmp_path, sig):
    """A signal handled inside a `__del__` raises there and Python drops it ('Exception ignored'):
    the run used to finish and replace the old output, exit 0 (the old rare failure of the test
    above, when the SIGTERM landed in a warp array's finalizer)."""
    ply, sc, out = _annotated(tmp_path, n=200), _scene(tmp_path), tmp_path / "o"
    assert main(_simulate(ply, out, sc, 2)) == 0
    old = _snapshot(out)
    proc = subprocess.run([sys.executable, "-c", _SIGNAL_IN_A_FINALIZER, str(int(sig)),
                           *_simulate(ply, out, sc, 30, "--force")], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300, preexec_fn=default_sigint)
    assert proc.returncode == (143 if sig == signal.SIGTERM else 130), proc.stderr
    assert _snapshot(out) == old
    assert [line for line in proc.stderr.splitlines() if line.strip()] == \
        ["pixie simulate: " + ("terminated (SIGTERM); partial output removed" if sig == signal.SIGTERM
                               else "interrupted")]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply", "o", "scene.json"]


def test_interrupt_dropped_by_a_finalizer_stops_a_single_file_output(tmp_path):
    """The same for one output file written through atomic_path (annotate, convert, prepare…), and
    the command's handlers are put back afterwards."""
    from pixie_gs import interrupts
    from pixie_gs.atomic import atomic_path

    class SignalInFinalizer:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGTERM)

    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT), sys.unraisablehook
    previous = interrupts.install()
    try:
        with pytest.raises(interrupts.Terminated):
            with atomic_path(tmp_path / "out.ply") as tmp:
                tmp.write_bytes(b"ply\nnew")
                SignalInFinalizer()
                assert interrupts.pending() == signal.SIGTERM  # recorded although the raise was dropped
    finally:
        interrupts.restore(previous)
    assert list(tmp_path.iterdir()) == []
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT), sys.unraisablehook) == before
    assert interrupts.pending() is None


_SECOND_CTRL_C_IN_CLEAN_UP = """
import os, signal, sys
from pixie_gs import atomic
from pixie_gs.cli.main import main
from pixie_gs.sim import frames

write = frames.FrameWriter.write
def write_then_ctrl_c(self, state):
    path = write(self, state)
    if state.index == 2:
        os.kill(os.getpid(), signal.SIGINT)
    return path

clean_up = atomic.remove_live_staging
def ctrl_c_again_then_clean_up():
    os.kill(os.getpid(), signal.SIGINT)  # the impatient second Ctrl-C, as main cleans up
    clean_up()

frames.FrameWriter.write = write_then_ctrl_c
atomic.remove_live_staging = ctrl_c_again_then_clean_up
sys.argv = ["pixie", *sys.argv[1:]]
sys.exit(main())
"""

_CTRL_C_AT_EXIT = """
import atexit, os, signal, sys, time
from pixie_gs.cli.main import main

def ctrl_c_at_exit(times):
    for _ in range(times):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)

atexit.register(ctrl_c_at_exit, int(sys.argv[1]))  # runs in the interpreter's exit, after the command ended
sys.argv = ["pixie", *sys.argv[2:]]
sys.exit(main())
"""


def test_second_ctrl_c_during_clean_up_and_ctrl_c_at_exit_print_no_traceback(tmp_path):
    """Once a command is interrupted or done, further signals are noted only: a second Ctrl-C while
    main removes the staging folder does not cut that clean-up, and one during the interpreter's exit
    does not print Python's KeyboardInterrupt traceback from an atexit callback."""
    ply, sc, out = _annotated(tmp_path, n=200), _scene(tmp_path), tmp_path / "o"
    assert main(_simulate(ply, out, sc, 2)) == 0
    old = _snapshot(out)
    proc = subprocess.run([sys.executable, "-c", _SECOND_CTRL_C_IN_CLEAN_UP, *_simulate(ply, out, sc, 30, "--force")],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300, preexec_fn=default_sigint)
    assert proc.returncode == 130, proc.stderr
    assert [line for line in proc.stderr.splitlines() if line.strip()] == ["pixie simulate: interrupted"]
    assert _snapshot(out) == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply", "o", "scene.json"]

    for times, code in ((1, 0), (2, -signal.SIGINT)):  # Ctrl-C twice at a (hung) exit ends it at once
        proc = subprocess.run([sys.executable, "-c", _CTRL_C_AT_EXIT, str(times), "info", str(ply)], cwd=tmp_path,
                              capture_output=True, text=True, timeout=300, preexec_fn=default_sigint)
        assert proc.returncode == code and "Traceback" not in proc.stderr, proc.stderr
        assert "KeyboardInterrupt" not in proc.stderr and "200" in proc.stdout  # the command's output is all there


def test_signal_inside_a_deferred_block_is_raised_when_the_block_ends():
    """`deferred()` keeps a few statements together: a SIGTERM sent inside does not cut them, and is
    raised as the block ends (also when another thread, which the main thread's mask does not cover,
    takes the signal: the handler then records instead of raising)."""
    import threading

    from pixie_gs import interrupts

    steps = []
    done = threading.Event()
    helper = threading.Thread(target=done.wait)  # a thread that does not block SIGTERM: the kernel hands it
    helper.start()  # the signal, and Python runs the handler in the main thread inside the block
    previous = interrupts.install()
    try:
        with pytest.raises(interrupts.Terminated):
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)
                steps.append("after the signal")
                time.sleep(0.01)
                steps.append("end of block")
            steps.append("after the block")  # never reached
    finally:
        interrupts.restore(previous)
        done.set()
        helper.join()
    assert steps == ["after the signal", "end of block"]


def test_tracks_are_memory_mapped_not_held_in_memory(tmp_path):
    """The writer hands `simulate` a (T,N,3) array backed by a file in the staging folder."""
    from pixie_gs.sim.frames import FrameWriter

    cloud = SplatCloud.from_arrays(np.random.default_rng(0).uniform(-1, 1, (100, 3)))
    writer = FrameWriter(tmp_path / "o", cloud, frames=1000)
    try:
        assert isinstance(writer.positions, np.memmap) and writer.positions.shape == (1000, 100, 3)
        assert Path(writer.positions.filename).parent == writer.stage_dir
    finally:
        writer.abort()
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------- measured tracks
@pytest.mark.parametrize("t,x,word", [
    (np.arange(5) / 10.0, np.zeros((5, 0, 3)), "zero tracked points"),
    (np.array([0.0, 1e300, 2e300]), np.zeros((3, 20, 3)), "frame interval"),
    (np.concatenate([np.arange(4) / 10.0, [1e9]]), np.zeros((5, 20, 3)), "simulation frames"),
    (np.array([0.0, 1e-9, 2e-9]), np.zeros((3, 20, 3)), "frame interval"),
    (np.arange(5) / 10.0, np.zeros((5, 0, 3)), "zero tracked points"),
])
def test_measured_tracks_with_no_points_or_absurd_times_are_refused(tmp_path, t, x, word):
    from pixie_gs.diagnose.measured import load_measured

    path = tmp_path / "m.npz"
    with open(path, "wb") as fh:
        np.savez(fh, t=t, x=x, ids=np.arange(x.shape[1]))
    cloud = SplatCloud.from_arrays(np.random.default_rng(0).uniform(-1, 1, (50, 3)))
    with pytest.raises(InputError, match=word):
        load_measured(path, cloud)


@pytest.mark.parametrize("command", ["prepare", "render", "convert"])
def test_drop_invalid_on_the_other_commands_that_read_splats(tmp_path, capsys, command):
    t = vertex_table(n=120, materials=True)
    t["opacity"][7] = np.nan
    path = write_ply(tmp_path / "bad.ply", t)
    out = {"prepare": tmp_path / "o.ply", "render": tmp_path / "o.png", "convert": tmp_path / "o.splat"}[command]
    args = {"prepare": ["prepare", path, out, "-q"], "render": ["render", path, "--out", out, "--device", "cpu",
                                                                 "--size", "64", "-q"],
            "convert": ["convert", path, out, "-q"]}[command]
    rc, err = run_cli(args, capsys)
    assert rc == 1 and "opacity" in one_error_line(err) and not out.exists()
    rc, err = run_cli(args + ["--drop-invalid"], capsys)
    assert rc == 0 and "dropped 1 of 120 Gaussians" in err and out.exists()


@pytest.mark.parametrize("state", [{"model": {}, "epoch": "3"}, {"weird": 1}, [1, 2], "garbage-bytes"])
def test_damaged_resume_state_is_one_line(tmp_path, capsys, state):
    import torch

    data = tmp_path / "data"
    (data / "train").mkdir(parents=True)
    ckpt = tmp_path / "m.pt"
    side = tmp_path / "m.pt.state.pt"
    if state == "garbage-bytes":
        side.write_bytes(b"PK\x03\x04 not a torch file")
    else:
        torch.save(state, side)
    rc, err = run_cli(["train", data, "--out", ckpt, "--resume", "--epochs", "1", "--device", "cpu", "-q"], capsys)
    line = one_error_line(err)
    assert rc == 1 and "state" in line and str(side) in line


# ------------------------------------------------------------------ killed writers and a full disk
_KILLED_WRITER = """
import os, signal, sys
from pixie_gs.atomic import atomic_path
with atomic_path(sys.argv[1], suffix=".ply.tmp") as tmp:
    tmp.write_bytes(b"ply\\npartial")
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_temp_file_of_a_sigkilled_writer_is_removed_by_the_next_write(tmp_path, capsys):
    """SIGKILL cannot be handled: the killed run's temp file stays, and the next run to the same
    OUT removes it (its PID is in the name and that process is gone)."""
    ply = write_ply(tmp_path / "in.ply", vertex_table())
    out = tmp_path / "out.ply"
    proc = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(out)], capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL
    stale = [p.name for p in tmp_path.iterdir() if p.name.startswith(".out.ply")]
    assert len(stale) == 1 and not out.exists()
    assert main(["convert", str(ply), str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply", "out.ply"]


def test_full_disk_while_writing_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    """Fault injection: the PLY writer hits ENOSPC half way through its file."""
    import errno

    from plyfile import PlyData

    def write_then_fail(self, stream):
        with open(stream, "wb") as fh:
            fh.write(b"ply\n" + b"\0" * 100)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(stream))

    ply = write_ply(tmp_path / "in.ply", vertex_table())
    before = ply.read_bytes()
    monkeypatch.setattr(PlyData, "write", write_then_fail)
    rc, err = run_cli(["convert", ply, tmp_path / "out.ply"], capsys)
    line = one_error_line(err)
    assert rc == 1 and "No space left on device" in line and str(tmp_path) in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply"] and ply.read_bytes() == before
