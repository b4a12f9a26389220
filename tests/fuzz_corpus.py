"""A generated corpus of bad inputs for every `pixie` command, and the harness that runs them.

Shared by tests/test_fuzz.py (a fast sample in CI) and benchmarks/bench_fuzz.py (the whole corpus
plus mutation fuzzing, with counts per command). Every case lives in its own folder; running it
in-process through `pixie_gs.cli.main.main` must give a non-zero exit, exactly one
`pixie CMD: error:` line on stderr, no traceback, no new file in the folder (no leftover) and every
input byte-identical afterwards. Bad files are written with plyfile/json/numpy/torch directly.
"""
from __future__ import annotations

import contextlib
import gzip
import hashlib
import io
import json
import os
import shutil
import signal
import tempfile
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from plyfile import PlyData, PlyElement

SH_C0 = 0.28209479177387814


def default_sigint() -> None:
    """`preexec_fn` for a `pixie` child that a test or benchmark interrupts: Ctrl-C as a terminal delivers
    it. A shell starts background jobs with SIGINT ignored and Python keeps an inherited SIG_IGN, so under
    `pytest &` the child would run on (the SIGINT case's old "rare flake": it failed every time in a
    background job without this)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


# ------------------------------------------------------------------------- valid building blocks
def vertex_table(n: int = 200, seed: int = 0, materials: bool = False, extras: bool = True) -> np.ndarray:
    """A 3DGS vertex table (degree-1 SH, a float feature extra, optional material attributes)."""
    rng = np.random.default_rng(seed)
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(9)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    if extras:
        names += ["feature_7"]
    dtype = [(k, "<f4") for k in names]
    if materials:
        dtype += [("material_id", "<i4"), ("E", "<f4"), ("nu", "<f4"), ("density", "<f4")]
    t = np.zeros(n, dtype=dtype)
    for k, v in zip("xyz", rng.uniform(-0.5, 0.5, (3, n))):
        t[k] = v
    for i, v in enumerate(((rng.random((n, 3)) - 0.5) / SH_C0).T):
        t[f"f_dc_{i}"] = v
    for i in range(9):
        t[f"f_rest_{i}"] = rng.normal(size=n) * 0.05
    t["opacity"] = rng.normal(size=n)
    for i in range(3):
        t[f"scale_{i}"] = rng.uniform(-4.5, -3.5, n)
    q = rng.normal(size=(n, 4))
    for i in range(4):
        t[f"rot_{i}"] = q[:, i]
    if extras:
        t["feature_7"] = rng.normal(size=n)
    if materials:
        t["material_id"] = 0
        t["E"] = rng.uniform(2e4, 4e4, n)
        t["nu"] = rng.uniform(0.3, 0.35, n)
        t["density"] = rng.uniform(100, 150, n)
    return t


def write_ply(path: Path, table: np.ndarray, text: bool = False) -> Path:
    PlyData([PlyElement.describe(table, "vertex")], text=text, byte_order="<").write(str(path))
    return path


def valid_ply_bytes(n: int = 40, materials: bool = False, seed: int = 0) -> bytes:
    buf = io.BytesIO()
    PlyData([PlyElement.describe(vertex_table(n, seed, materials), "vertex")], byte_order="<").write(buf)
    return buf.getvalue()


def scene_dict() -> dict:
    return {"up": "z", "object": {"size_m": 0.3, "position": [0.0, 0.0, 0.05]}, "domain": {"size_m": 1.0, "grid": 16}}


# ------------------------------------------------------------------------- bad splat files
def bad_splats(rng: np.random.Generator) -> dict[str, Callable[[Path], None]]:
    """name → writer of one bad splat file at the given path."""
    good = valid_ply_bytes(40, materials=True)
    header_end = good.index(b"end_header\n") + len(b"end_header\n")
    out: dict[str, Callable[[Path], None]] = {}

    def raw(data: bytes) -> Callable[[Path], None]:
        return lambda p: p.write_bytes(data)

    out["empty file"] = raw(b"")
    out["text"] = raw(b"hello, not a splat\n")
    out["random bytes"] = raw(rng.bytes(3000))
    out["magic only"] = raw(b"ply\n")
    out["header only"] = raw(good[:header_end])
    out["truncated data"] = raw(good[:-37])
    out["truncated header"] = raw(good[:header_end // 2])
    out["count larger"] = raw(good.replace(b"element vertex 40", b"element vertex 41"))
    out["count smaller"] = raw(good.replace(b"element vertex 40", b"element vertex 30"))
    out["count negative"] = raw(good.replace(b"element vertex 40", b"element vertex -4"))
    out["count huge"] = raw(good.replace(b"element vertex 40", b"element vertex 99999999999999"))
    out["count text"] = raw(good.replace(b"element vertex 40", b"element vertex forty"))
    out["bad format"] = raw(good.replace(b"binary_little_endian", b"binary_middle_endian"))
    out["unknown type"] = raw(good.replace(b"property float x", b"property quaternion x", 1))
    out["list property"] = raw(good[:header_end].replace(b"property float x\n", b"property list uchar float x\n", 1)
                               + good[header_end:])
    out["no vertex"] = raw(good.replace(b"element vertex", b"element vortex"))
    out["missing scale"] = raw(good.replace(b"property float scale_1\n", b""))
    out["nul in header"] = raw(good[:20] + b"\x00" + good[21:])
    out["utf8 garbage header"] = raw(b"ply\nformat ascii 1.0\ncomment \xff\xfe\nelement vertex 1\nend_header\n1\n")
    out["ascii bad number"] = raw(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                                  b"property float z\nend_header\n1 2 banana\n")
    out["zero vertices"] = lambda p: write_ply(p, vertex_table(0, materials=True))
    for prop, value in [("opacity", np.nan), ("f_dc_0", np.inf), ("f_rest_3", np.nan), ("feature_7", np.nan),
                        ("x", np.nan), ("y", np.inf), ("z", 1e-40), ("x", 3e38), ("scale_0", np.nan),
                        ("scale_2", 80.0), ("scale_1", -90.0), ("rot_0", np.nan), ("opacity", -np.inf),
                        ("f_rest_8", 1e30), ("E", -1.0), ("E", np.nan), ("nu", 0.5), ("nu", -0.1),
                        ("density", 0.0), ("density", np.inf), ("material_id", 99), ("material_id", -1)]:
        def nan_writer(p: Path, prop=prop, value=value) -> None:
            t = vertex_table(40, materials=True)
            t[prop][int(rng.integers(0, 40))] = value
            write_ply(p, t)
        out[f"{prop}={value:g}"] = nan_writer

    def zero_quat(p: Path) -> None:
        t = vertex_table(40, materials=True)
        for k in ("rot_0", "rot_1", "rot_2", "rot_3"):
            t[k][5] = 0.0
        write_ply(p, t)
    out["zero quaternion"] = zero_quat

    def all_denormal(p: Path) -> None:
        t = vertex_table(40, materials=True)
        for k in "xyz":
            t[k] = rng.uniform(-1, 1, 40) * 1e-39
        write_ply(p, t)
    out["denormal positions"] = all_denormal

    def sh_count(p: Path) -> None:
        t = vertex_table(40, materials=True)
        from numpy.lib import recfunctions

        write_ply(p, recfunctions.drop_fields(t, "f_rest_8", usemask=False))
    out["f_rest count 8"] = sh_count
    out["splat size not 32k"] = raw(rng.bytes(32 * 5 + 7))
    out["spz garbage"] = raw(b"\x1f\x8b\x08\x00" + rng.bytes(200))
    return out


def no_material_splat(p: Path) -> None:
    write_ply(p, vertex_table(40, materials=False))


# ------------------------------------------------------------------------- other bad inputs
def bad_scenes() -> dict[str, bytes]:
    s = scene_dict

    def js(d) -> bytes:
        return json.dumps(d).encode()

    return {
        "scene not utf8": b'{"up": "\xff"}',
        "scene nested": b"[" * 100_000 + b"]" * 100_000,
        "scene huge int": b'{"damping": 1' + b"0" * 400 + b"}",
        "scene 5000 digits": b'{"damping": 1' + b"0" * 5000 + b"}",
        "scene 1e300 size": js({**s(), "domain": {"size_m": 1e300, "grid": 16}}),
        "scene grid 100000": js({**s(), "domain": {"size_m": 1.0, "grid": 100000}}),
        "scene grid 3000": js({**s(), "domain": {"size_m": 1.0, "grid": 3000}}),
        "scene grid text": js({**s(), "domain": {"size_m": 1.0, "grid": "64"}}),
        "scene list top": b"[1, 2, 3]",
        "scene unknown key": js({**s(), "gravityy": [0, 0, -9.8]}),
        "scene NaN": b'{"damping": NaN}',
        "scene Infinity": b'{"gravity": [0, 0, -Infinity]}',
        "scene empty": b"",
        "scene truncated": js(s())[:-5],
        "scene up": js({**s(), "up": "w"}),
        "scene cfl": js({**s(), "solver": {"cfl": 0}}),
        "scene region": js({**s(), "fixed": [{"region": {"min": [1, 1, 1], "max": [0, 0, 0]}}]}),
        "scene part id": b'{"part_overrides": {"1' + b"0" * 200 + b'": {}}}',
        "scene too small": js({**s(), "domain": {"size_m": 0.01, "grid": 16}}),
        "scene wind": js({**s(), "wind": [{"acceleration": [1, 2]}]}),
    }


def damaged_checkpoints() -> dict[str, Callable[[Path], None]]:
    """name → writer of one damaged checkpoint (torch imported lazily)."""
    def from_payload(change: Callable[[dict], None]) -> Callable[[Path], None]:
        def write(p: Path) -> None:
            import torch

            from pixie_gs.model.checkpoint import DEFAULT_CHECKPOINT

            payload = torch.load(DEFAULT_CHECKPOINT, map_location="cpu", weights_only=True)
            change(payload)
            torch.save(payload, p)
        return write

    def nan_weight(pl: dict) -> None:
        key = next(k for k, v in pl["state_dict"].items() if v.is_floating_point())
        pl["state_dict"][key] = pl["state_dict"][key].clone()
        pl["state_dict"][key].view(-1)[3] = float("nan")

    def pickle_file(p: Path) -> None:
        import pickle

        p.write_bytes(pickle.dumps({"format": "x", "evil": os.system.__name__}))

    out: dict[str, Callable[[Path], None]] = {
        "ckpt nan weight": from_payload(nan_weight),
        "ckpt missing config": from_payload(lambda pl: pl.pop("config")),
        "ckpt missing features": from_payload(lambda pl: pl.pop("features")),
        "ckpt missing state_dict": from_payload(lambda pl: pl.pop("state_dict")),
        "ckpt negative channels": from_payload(lambda pl: pl["config"].update(base_channels=-8)),
        "ckpt resolution 0": from_payload(lambda pl: pl["features"].update(resolution=0)),
        "ckpt resolution 4096": from_payload(lambda pl: pl["features"].update(resolution=4096)),
        "ckpt channels text": from_payload(lambda pl: pl["config"].update(projector_out="16")),
        "ckpt extra names int": from_payload(lambda pl: pl["features"].update(extra_names=[1, 2])),
        "ckpt config list": from_payload(lambda pl: pl.update(config=[1, 2])),
        "ckpt wrong format": from_payload(lambda pl: pl.update(format="other")),
        "ckpt version 99": from_payload(lambda pl: pl.update(format_version=99)),
        "ckpt shape mismatch": from_payload(lambda pl: pl["config"].update(projector_hidden=64)),
        "ckpt multipliers huge": from_payload(lambda pl: pl["config"].update(multipliers=[1, 64, 64])),
        "ckpt pickle": pickle_file,
        "ckpt garbage": lambda p: p.write_bytes(b"PK\x03\x04" + b"\x00" * 100),
        "ckpt empty": lambda p: p.write_bytes(b""),
    }
    return out


def bad_indexes() -> dict[str, bytes]:
    return {
        "index ints": b'{"objects": [1, 2, 3]}',
        "index not utf8": b'\xff\xfe{"objects": []}',
        "index absolute": b'{"objects": [{"file": "/etc/passwd"}]}',
        "index dotdot": b'{"objects": [{"file": "../../../etc/passwd"}]}',
        "index file int": b'{"objects": [{"file": 7}]}',
        "index nested": b"[" * 100_000 + b"]" * 100_000,
        "index objects dict": b'{"objects": {"a": 1}}',
        "index missing file": b'{"objects": [{"file": "nothere.ply"}]}',
        "index empty": b"",
        "index list": b"[]",
    }


def bad_tables() -> dict[str, bytes]:
    part = {"material": "jelly", "E": 1e4, "nu": 0.3, "density": 100}

    def js(d) -> bytes:
        return json.dumps(d).encode()

    return {
        "table part string": js({"classes": {"a": {"recipe": "box", "parts": {"p": "jelly"}}}}),
        "table presence text": js({"classes": {"a": {"recipe": "box", "parts": {"p": {**part, "presence": "x"}}}}}),
        "table constraints int": js({"classes": {"a": {"recipe": "box", "parts": {"p": part}, "constraints": 5}}}),
        "table widen text": js({"classes": {"a": {"recipe": "box", "parts": {"p": part}}}, "widen": {"E_rel": "x"}}),
        "table classes list": js({"classes": [1, 2]}),
        "table nu range": js({"classes": {"a": {"recipe": "box", "parts": {"p": {**part, "nu": [0.4, 0.6]}}}}}),
        "table not utf8": b'{"classes": "\xff"}',
        "table recipe unknown": js({"classes": {"a": {"recipe": "no_such_recipe", "parts": {"p": part}}}}),
        "table E text": js({"classes": {"a": {"recipe": "box", "parts": {"p": {**part, "E": "stiff"}}}}}),
        "table part_map list": js({"classes": {"a": {"recipe": "box", "parts": {"p": part}, "part_map": [1]}}}),
    }


def bad_tracks(rng: np.random.Generator) -> dict[str, Callable[[Path], None]]:
    def npz(**arrays) -> Callable[[Path], None]:
        def write(p: Path) -> None:
            with open(p, "wb") as fh:
                np.savez(fh, **arrays)
        return write

    def pickled(p: Path) -> None:
        with open(p, "wb") as fh:
            np.savez(fh, t=np.arange(5) / 10.0, x=np.array([{"a": 1}], dtype=object))

    x = rng.uniform(-0.5, 0.5, (5, 20, 3))
    return {
        "tracks zero points": npz(t=np.arange(5) / 10.0, x=np.zeros((5, 0, 3))),
        "tracks huge times": npz(t=np.array([0.0, 1e300, 2e300]), x=x[:3]),
        "tracks long run": npz(t=np.concatenate([np.arange(4) / 10.0, [1e9]]), x=x),
        "tracks nan visible": npz(t=np.arange(5) / 10.0, x=np.where(rng.random(x.shape) < 0.1, np.nan, x)),
        "tracks decreasing t": npz(t=np.arange(5)[::-1] / 10.0, x=x),
        "tracks wrong shape": npz(t=np.arange(5) / 10.0, x=x[:, :, :2]),
        "tracks missing x": npz(t=np.arange(5) / 10.0),
        "tracks text t": npz(t=np.array(["a", "b", "c"]), x=x[:3]),
        "tracks ids out of range": npz(t=np.arange(5) / 10.0, x=x, ids=np.arange(20) + 10_000),
        "tracks pickle": pickled,
        "tracks garbage": lambda p: p.write_bytes(b"PK\x03\x04" + rng.bytes(300)),
        "tracks not zip": lambda p: p.write_bytes(rng.bytes(300)),
    }


# ------------------------------------------------------------------------- the corpus
@dataclass
class Case:
    """One bad invocation: `make(folder)` writes its inputs and returns the argv (after `pixie`)."""

    command: str
    name: str
    make: Callable[[Path], list[str]]
    codes: tuple[int, ...] = (1,)
    slow: bool = False  # runs a model or a simulation before it can fail


@dataclass
class Outcome:
    case: Case
    code: int | None
    problems: list[str] = field(default_factory=list)
    seconds: float = 0.0


def corpus(seed: int = 0) -> list[Case]:
    """Every bad input × the commands that read it (≥ 300 cases)."""
    rng = np.random.default_rng(seed)
    cases: list[Case] = []
    splats = bad_splats(rng)
    scenes = bad_scenes()
    ckpts = damaged_checkpoints()
    indexes = bad_indexes()
    tables = bad_tables()
    tracks = bad_tracks(rng)

    def good_annotated(folder: Path) -> Path:
        return write_ply(folder / "good.ply", vertex_table(40, materials=True))

    def good_scene(folder: Path) -> Path:
        (folder / "scene.json").write_text(json.dumps(scene_dict()))
        return folder / "scene.json"

    for name, writer in splats.items():
        def info(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.ply")
            return ["info", str(folder / "bad.ply")]

        def annotate(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.ply")
            return ["annotate", str(folder / "bad.ply"), str(folder / "out.ply"), "--device", "cpu", "-q"]

        def simulate(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.ply")
            return ["simulate", str(folder / "bad.ply"), "--out", str(folder / "frames"), "--scene",
                    str(good_scene(folder)), "--frames", "2", "--device", "cpu", "-q"]

        def diagnose(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.ply")
            tracks["tracks nan visible"](folder / "m.npz")
            return ["diagnose", str(folder / "bad.ply"), str(folder / "m.npz"), "--out", str(folder / "diag"),
                    "--device", "cpu", "-q"]

        def convert(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.ply")
            return ["convert", str(folder / "bad.ply"), str(folder / "out.ply"), "--count", "100"]

        def prepare(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.ply")
            return ["prepare", str(folder / "bad.ply"), str(folder / "out.ply"), "-q"]

        def render(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.ply")
            return ["render", str(folder / "bad.ply"), "--out", str(folder / "out.png"), "--device", "cpu", "-q"]

        for cmd, make in (("info", info), ("annotate", annotate), ("simulate", simulate), ("diagnose", diagnose),
                          ("convert", convert), ("prepare", prepare), ("render", render)):
            cases.append(Case(cmd, name, make))

    def no_materials(folder: Path) -> list[str]:
        no_material_splat(folder / "plain.ply")
        return ["simulate", str(folder / "plain.ply"), "--out", str(folder / "f"), "--device", "cpu", "-q"]
    cases.append(Case("simulate", "no materials", no_materials))

    for name, content in scenes.items():
        def sim_scene(folder: Path, content=content) -> list[str]:
            (folder / "scene.json").write_bytes(content)
            return ["simulate", str(good_annotated(folder)), "--out", str(folder / "frames"), "--scene",
                    str(folder / "scene.json"), "--frames", "2", "--device", "cpu", "-q"]

        def diag_scene(folder: Path, content=content) -> list[str]:
            (folder / "scene.json").write_bytes(content)
            tracks["tracks nan visible"](folder / "m.npz")
            return ["diagnose", str(good_annotated(folder)), str(folder / "m.npz"), "--scene",
                    str(folder / "scene.json"), "--out", str(folder / "diag"), "--device", "cpu", "-q"]
        cases.append(Case("simulate", name, sim_scene))
        cases.append(Case("diagnose", name, diag_scene))

    for name, flags in {"frames 1e9": ["--frames", "1000000000"], "frames 0": ["--frames", "0"],
                        "frames -3": ["--frames", "-3"], "fps 1e-300": ["--fps", "1e-300"], "fps nan": ["--fps", "nan"],
                        "fps inf": ["--fps", "inf"], "fps -1": ["--fps", "-1"], "fps text": ["--fps", "fast"]}.items():
        def sim_flags(folder: Path, flags=flags) -> list[str]:
            return ["simulate", str(good_annotated(folder)), "--out", str(folder / "frames"), "--scene",
                    str(good_scene(folder)), "--device", "cpu", "-q", *flags]
        cases.append(Case("simulate", name, sim_flags, codes=(2,) if name == "fps text" else (1,)))

    def out_is_file(folder: Path) -> list[str]:
        (folder / "frames").write_text("not a folder")
        return ["simulate", str(good_annotated(folder)), "--out", str(folder / "frames"), "-q", "--device", "cpu"]

    def input_inside_out(folder: Path) -> list[str]:
        (folder / "o").mkdir()
        write_ply(folder / "o" / "frame_00000.ply", vertex_table(40, materials=True))
        return ["simulate", str(folder / "o" / "frame_00000.ply"), "--out", str(folder / "o"), "--force",
                "--scene", str(good_scene(folder)), "--frames", "2", "--device", "cpu", "-q"]

    def scene_inside_out(folder: Path) -> list[str]:
        (folder / "o").mkdir()
        (folder / "o" / "scene.json").write_text(json.dumps(scene_dict()))
        return ["simulate", str(good_annotated(folder)), "--out", str(folder / "o"), "--force",
                "--scene", str(folder / "o" / "scene.json"), "--frames", "2", "--device", "cpu", "-q"]

    def out_parent_missing(folder: Path) -> list[str]:
        return ["simulate", str(good_annotated(folder)), "--out", str(folder / "a" / "b"), "-q", "--device", "cpu"]

    def fifo_input(folder: Path) -> list[str]:
        os.mkfifo(folder / "pipe.ply")
        return ["simulate", str(folder / "pipe.ply"), "--out", str(folder / "f"), "-q", "--device", "cpu"]

    def scene_fifo(folder: Path) -> list[str]:
        os.mkfifo(folder / "scene.json")
        return ["simulate", str(good_annotated(folder)), "--out", str(folder / "f"), "--scene",
                str(folder / "scene.json"), "-q", "--device", "cpu"]
    for name, make in (("out is a file", out_is_file), ("input inside --out", input_inside_out),
                       ("scene inside --out", scene_inside_out), ("out parent missing", out_parent_missing),
                       ("fifo input", fifo_input), ("fifo scene", scene_fifo)):
        cases.append(Case("simulate", name, make))

    for name, writer in ckpts.items():
        def ann_ckpt(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.pt")
            return ["annotate", str(good_annotated(folder)), str(folder / "out.ply"), "--checkpoint",
                    str(folder / "bad.pt"), "--device", "cpu", "-q"]

        def eval_ckpt(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.pt")
            return ["evaluate", str(folder / "bad.pt"), str(folder / "nodata"), "--device", "cpu", "--json",
                    str(folder / "m.json")]

        def demo_ckpt(folder: Path, writer=writer) -> list[str]:
            writer(folder / "bad.pt")
            return ["demo", "--checkpoint", str(folder / "bad.pt"), "--out", str(folder / "demo"), "--device", "cpu",
                    "-q"]
        cases.append(Case("annotate", name, ann_ckpt))
        cases.append(Case("evaluate", name, eval_ckpt))
        cases.append(Case("demo", name, demo_ckpt))

    for name, content in indexes.items():
        def data_dir(folder: Path, content=content) -> Path:
            split = folder / "data" / "test"
            split.mkdir(parents=True)
            (split / "index.json").write_bytes(content)
            (folder / "data" / "train").mkdir()
            (folder / "data" / "train" / "index.json").write_bytes(content)
            (folder / "data" / "val").mkdir()
            (folder / "data" / "val" / "index.json").write_bytes(content)
            return folder / "data"

        def ev(folder: Path, data_dir=data_dir) -> list[str]:
            return ["evaluate", "default", str(data_dir(folder)), "--device", "cpu"]

        def tr(folder: Path, data_dir=data_dir) -> list[str]:
            return ["train", str(data_dir(folder)), "--out", str(folder / "m.pt"), "--epochs", "1", "--device", "cpu",
                    "-q"]
        cases.append(Case("evaluate", name, ev))
        cases.append(Case("train", name, tr))

    for name, content in tables.items():
        def gen(folder: Path, content=content) -> list[str]:
            (folder / "table.json").write_bytes(content)
            return ["generate", str(folder / "gen"), "--count", "1", "--table", str(folder / "table.json"), "-q"]
        cases.append(Case("generate", name, gen))
    for name, flags in {"count 0": ["--count", "0"], "count -5": ["--count", "-5"],
                        "unknown class": ["--count", "1", "--classes", "spaceship"],
                        "gaussians 0": ["--count", "1", "--gaussians", "0"],
                        "workers 0": ["--count", "1", "--workers", "0"]}.items():
        def gen_flags(folder: Path, flags=flags) -> list[str]:
            return ["generate", str(folder / "gen"), "-q", *flags]
        cases.append(Case("generate", name, gen_flags))

    for name, writer in tracks.items():
        def diag_tracks(folder: Path, writer=writer) -> list[str]:
            writer(folder / "m.npz")
            return ["diagnose", str(good_annotated(folder)), str(folder / "m.npz"), "--out", str(folder / "diag"),
                    "--device", "cpu", "-q"]
        cases.append(Case("diagnose", name, diag_tracks))

    meshes = {"mesh random.obj": ("x.obj", rng.bytes(400)), "mesh random.stl": ("x.stl", rng.bytes(400)),
              "mesh random.glb": ("x.glb", b"glTF" + rng.bytes(400)), "mesh random.off": ("x.off", rng.bytes(400)),
              "mesh random.gltf": ("x.gltf", rng.bytes(400)), "mesh empty.obj": ("x.obj", b""),
              "mesh nan.obj": ("x.obj", b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
              "mesh points.obj": ("x.obj", b"v 0 0 0\nv 1 0 0\n"),
              "mesh flat.obj": ("x.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"),
              "mesh bad index.obj": ("x.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99\n"),
              "mesh non-utf8.obj": ("x.obj", b"v 1 2 3\nv 1 \xff 3\nv 0 0 1\nf 1 2 3\n"),
              "mesh unknown.xyz2": ("x.xyz2", b"1 2 3\n"),
              "mesh huge count": ("x.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")}
    for name, (fname, content) in meshes.items():
        def conv(folder: Path, fname=fname, content=content, name=name) -> list[str]:
            (folder / fname).write_bytes(content)
            extra = ["--count", "100000000000"] if name == "mesh huge count" else ["--count", "200"]
            return ["convert", str(folder / fname), str(folder / "out.ply"), *extra]
        cases.append(Case("convert", name, conv))

    for name, flags in {"render size 0": ["--size", "0"], "render size huge": ["--size", "10000000"],
                        "render camera garbage": ["--camera", "cams.json"], "render frames -1": ["--frames", "-1"],
                        "render fps 1e-300": ["--fps", "1e-300"]}.items():
        def render_flags(folder: Path, flags=flags) -> list[str]:
            (folder / "cams.json").write_bytes(b'{"not": "cameras"}')
            return ["render", str(good_annotated(folder)), "--out", str(folder / "o.png"), "--device", "cpu",
                    "-q", *flags]
        cases.append(Case("render", name, render_flags))
    for name, flags in {"prepare crop garbage": ["--crop", "box:1,2"], "prepare up zero": ["--up", "0,0,0"],
                        "prepare up nan": ["--up", "nan,0,1"]}.items():
        def prepare_flags(folder: Path, flags=flags) -> list[str]:
            return ["prepare", str(good_annotated(folder)), str(folder / "o.ply"), "-q", *flags]
        cases.append(Case("prepare", name, prepare_flags, codes=(1, 2)))

    for name, flags in {"demo frames 1": ["--frames", "1"], "demo frames -1": ["--frames", "-1"],
                        "demo missing checkpoint": ["--checkpoint", "nothere.pt"]}.items():
        def demo(folder: Path, flags=flags) -> list[str]:
            return ["demo", "--out", str(folder / "demo"), "--device", "cpu", "-q", *flags]
        cases.append(Case("demo", name, demo))
    return cases


# ------------------------------------------------------------------------- the harness
def digest(folder: Path) -> dict[str, str]:
    """sha256 of every regular file under `folder` (relative path → hex), FIFOs noted, not read."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_fifo():
            out[rel] = "fifo"
        elif p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
        elif p.is_dir():
            out[rel] = "dir"
    return out


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def run_case(case: Case, folder: Path, timeout_s: float = 120.0) -> Outcome:
    """Run one case in-process; an Outcome listing every broken promise (empty = fine)."""
    import time

    from pixie_gs.cli.main import main

    folder.mkdir(parents=True, exist_ok=True)
    argv = case.make(folder)
    before = digest(folder)
    err, out = io.StringIO(), io.StringIO()
    problems: list[str] = []
    code: int | None = None
    caught: list[warnings.WarningMessage] = []
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")  # a warning printed once per process would hide from later cases
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse usage errors
                code = exc.code if isinstance(exc.code, int) else 2
    except Hang:
        problems.append("hang")
    except BaseException as exc:  # noqa: BLE001 - a traceback is exactly what we count
        problems.append(f"traceback: {type(exc).__name__}: {str(exc).splitlines()[0][:160] if str(exc) else ''}")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    seconds = time.perf_counter() - t0
    text = err.getvalue()
    noisy = sorted({f"{w.category.__name__} at {Path(w.filename).name}:{w.lineno}" for w in caught
                    if issubclass(w.category, (RuntimeWarning, UserWarning))})
    if noisy:  # a user would see these lines beside the one error line (or after a success)
        problems.append(f"warnings: {', '.join(noisy)}")
    if code is not None:
        if code == 0:
            problems.append("wrong success")
        elif code not in case.codes:
            problems.append(f"exit {code} (expected {case.codes})")
        # count error messages, not lines: a progress bar may share the line (no terminal to clear it)
        errors = [m for m in text.split(f"pixie {case.command}: error:")[1:]]
        if code == 2 and not errors:
            errors = [line for line in text.splitlines() if "error:" in line]
        if "Traceback" in text:
            problems.append("traceback in stderr")
        elif code != 0 and len(errors) != 1:
            problems.append(f"{len(errors)} error lines: {text.strip()[:200]!r}")
    after = digest(folder)
    changed = [k for k in before if after.get(k) != before[k]]
    new = [k for k in after if k not in before]
    if changed:
        problems.append(f"modified inputs: {changed}")
    if new:
        problems.append(f"leftovers: {new}")
    return Outcome(case, code, problems, seconds)


# ------------------------------------------------------------------------- mutation fuzzing
SPECIAL_FLOAT32 = np.array([np.nan, np.inf, -np.inf, 1e38, 1e-42, -0.0, 3e30], np.float32)
SPLAT_SUFFIXES = ("ply", "compressed.ply", "splat", "spz")  # every format `read_splat` detects


def valid_splat_bytes(suffix: str, n: int = 300, seed: int = 0) -> bytes:
    """A valid splat in the format of `suffix` (one of SPLAT_SUFFIXES): the plyfile-made table of
    `valid_ply_bytes`, written for the other formats by pixie's own writers (the readers are what is fuzzed)."""
    if suffix == "ply":
        return valid_ply_bytes(n, seed=seed)
    from pixie_gs.formats import write_any
    from pixie_gs.splat import read_splat

    with tempfile.TemporaryDirectory() as tmp:
        source, target = Path(tmp) / "v.ply", Path(tmp) / f"v.{suffix}"
        source.write_bytes(valid_ply_bytes(n, seed=seed))
        write_any(read_splat(source), target)
        return target.read_bytes()


def _flip(b: bytearray, rng: np.random.Generator) -> bytearray:
    """A few bytes anywhere set to random values."""
    for _ in range(int(rng.integers(1, 8))):
        b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
    return b


def _insert(b: bytearray, rng: np.random.Generator) -> bytearray:
    """1–63 random bytes inserted at a random place."""
    at = int(rng.integers(0, len(b)))
    b[at:at] = rng.bytes(int(rng.integers(1, 64)))
    return b


def mutate_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    """One format-blind mutation: byte flips, truncation, insertion, or a special float32 (NaN, ±inf, huge,
    subnormal) over 4 aligned bytes. For the headerless formats (.splat records, the inflated .spz stream)."""
    b = bytearray(data)
    kind = int(rng.integers(0, 4))
    if kind == 0 and b:
        b = _flip(b, rng)
    elif kind == 1:
        b = b[:int(rng.integers(0, len(b) + 1))]
    elif kind == 2 and b:
        b = _insert(b, rng)
    elif len(b) >= 4:
        at = 4 * int(rng.integers(0, len(b) // 4))
        b[at:at + 4] = SPECIAL_FLOAT32[int(rng.integers(0, len(SPECIAL_FLOAT32)))].tobytes()
    return bytes(b)


def mutate_splat(data: bytes, suffix: str, rng: np.random.Generator) -> bytes:
    """One mutation of a splat file of the format `suffix`: header-aware for the PLY formats; for .spz
    mostly of the inflated stream, deflated again so the reader gets past gzip (else of the gzip bytes)."""
    if suffix in ("ply", "compressed.ply"):
        return mutate(data, rng)
    if suffix == "spz" and rng.random() < 0.85:
        try:
            return gzip.compress(mutate_bytes(gzip.decompress(data), rng))
        except (OSError, EOFError, zlib.error):  # an earlier mutation broke the gzip stream itself
            pass
    return mutate_bytes(data, rng)


MESH_SUFFIXES_FUZZED = ("glb", "obj", "stl", "ply", "off")
TEXT_TOKENS = [b"nan", b"inf", b"-inf", b"1e308", b"-1", b"0", b"99999999", b"-99999", b"1.5", b"", b"x", b"1/2/3",
               b"0/0"]


def valid_mesh_bytes(suffix: str, seed: int = 0) -> bytes:
    """An icosphere (162 vertices) with random vertex colours, as trimesh (not pixie) writes it as `suffix`."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    rgba = np.random.default_rng(seed).integers(0, 256, (len(sphere.vertices), 4))
    sphere.visual.vertex_colors = rgba.astype(np.uint8)
    data = sphere.export(file_type=suffix)
    return data.encode() if isinstance(data, str) else data


def mutate_mesh(data: bytes, suffix: str, rng: np.random.Generator) -> bytes:
    """One mutation of a mesh file: for OBJ/OFF mostly of one text line (a field replaced by a special token,
    the line deleted or repeated), header-aware for PLY, format-blind for GLB and STL."""
    if suffix in ("obj", "off") and rng.random() < 0.8:
        lines = data.split(b"\n")
        j = int(rng.integers(0, len(lines)))
        fields = lines[j].split(b" ")
        r = rng.random()
        if r < 0.6 and len(fields) > 1:
            fields[int(rng.integers(1, len(fields)))] = TEXT_TOKENS[int(rng.integers(0, len(TEXT_TOKENS)))]
            lines[j] = b" ".join(fields)
        elif r < 0.8:
            del lines[j]
        else:
            lines.insert(j, lines[int(rng.integers(0, len(lines)))])
        return b"\n".join(lines)
    return mutate(data, rng) if suffix == "ply" else mutate_bytes(data, rng)


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One random mutation of a PLY file: byte flips, truncation, insertion, header-number edits, splices."""
    b = bytearray(data)
    kind = int(rng.integers(0, 7))
    header_end = data.find(b"end_header\n")
    if kind == 0 and b:  # flip a few bytes anywhere
        b = _flip(b, rng)
    elif kind == 1:  # truncate
        b = b[:int(rng.integers(0, len(b) + 1))]
    elif kind == 2 and b:  # insert junk
        b = _insert(b, rng)
    elif kind == 3 and header_end > 0:  # change a number in the header
        head = data[:header_end].decode("ascii", "replace")
        nums = [tok for tok in head.split() if tok.isdigit()]
        if nums:
            tok = nums[int(rng.integers(0, len(nums)))]
            new = str(int(rng.choice([0, 1, int(tok) - 1, int(tok) + 1, int(tok) * 2, 2**31, 10**15])))
            head = head.replace(tok, new, 1)
        b = bytearray(head.encode() + data[header_end:])
    elif kind == 4 and header_end > 0:  # corrupt float payload with special values
        body = np.frombuffer(bytes(b[header_end + 11:]), dtype="<f4").copy() if (len(b) - header_end - 11) % 4 == 0 \
            else None
        if body is not None and len(body):
            idx = rng.integers(0, len(body), int(rng.integers(1, 5)))
            body[idx] = rng.choice(SPECIAL_FLOAT32, len(idx))
            b = bytearray(bytes(b[:header_end + 11]) + body.tobytes())
    elif kind == 5 and header_end > 0:  # swap/duplicate a header line
        lines = data[:header_end].split(b"\n")
        i, j = (int(v) for v in rng.integers(1, max(2, len(lines)), 2))
        if rng.random() < 0.5:
            lines[i], lines[j] = lines[j], lines[i]
        else:
            lines.insert(i, lines[j])
        b = bytearray(b"\n".join(lines) + data[header_end:])
    else:  # change the type of a property
        b = bytearray(data.replace(b"property float", rng.choice([b"property double", b"property uchar",
                                                                  b"property int", b"property list uchar float"]),
                                   1 + int(rng.integers(0, 3))))
    return bytes(b)


def fuzz_convert_once(data: bytes, suffix: str, folder: Path) -> Outcome:
    """`pixie convert` of one mutated mesh to a 200-Gaussian splat: an error (one line) or a valid splat written,
    and nothing else."""
    mesh, out = folder / f"m.{suffix}", folder / "out.ply"

    def make(f: Path) -> list[str]:
        mesh.write_bytes(data)
        return ["convert", str(mesh), str(out), "--count", "200", "-q"]

    outcome = run_case(Case("convert", "mesh mutation", make), folder, timeout_s=30)
    if outcome.code == 0 and {"wrong success", "leftovers: ['out.ply']"} <= set(outcome.problems):
        from pixie_gs.splat import read_splat

        outcome.problems = [p for p in outcome.problems if p not in ("wrong success", "leftovers: ['out.ply']")]
        try:
            cloud = read_splat(out)
            cloud.validate()
            if len(cloud) != 200 or not np.isfinite(cloud.covariances()).all():
                outcome.problems.append("wrong success: the splat written is not 200 finite Gaussians")
        except Exception as exc:  # noqa: BLE001
            outcome.problems.append(f"wrong success: convert ok but its output does not read ({type(exc).__name__})")
    mesh.unlink(missing_ok=True)
    out.unlink(missing_ok=True)
    return outcome


def through_the_pipeline_once(data: bytes, suffix: str, folder: Path, frames: int = 3) -> dict[str, Outcome]:
    """A splat that reads as valid through `pixie annotate`, `pixie render` of the result (a 96-px PNG of its
    material), `pixie simulate` (`frames` frames) and `pixie render` of the frames: each must succeed with finite
    results, or fail in one line (a NaN result is exit 3), never crash. Returns the outcomes of the steps that
    ran, by command ("annotate", "render", "simulate", "render frames"); a step runs only after its input was
    made. Exit 1 in one line is allowed too: a valid splat can still be refused, e.g. a flat one that `prepare`
    reads as ground alone ("found no object to simulate"). Their problems list what went wrong."""
    from pixie_gs.splat import read_splat

    source, annotated, sim_dir, png = folder / f"in.{suffix}", folder / "out.ply", folder / "sim", folder / "o.png"

    def step(name: str, command: str, argv: list[str]) -> Outcome:
        outcome = run_case(Case(command, "accepted mutation", lambda f: argv, codes=(1, 3)), folder, timeout_s=300)
        if outcome.code == 0:  # success is right here, and the outputs it made are no leftovers
            outcome.problems = [p for p in outcome.problems if p != "wrong success" and not p.startswith("leftovers")]
        outcomes[name] = outcome
        return outcome

    outcomes: dict[str, Outcome] = {}
    source.write_bytes(data)
    if step("annotate", "annotate", ["annotate", str(source), str(annotated), "--device", "cpu", "-q"]).code == 0:
        if not all(np.isfinite(a).all() for a in read_splat(annotated).get_materials()):
            outcomes["annotate"].problems.append("wrong success: non-finite materials written")
        step("render", "render", ["render", str(annotated), "--out", str(png), "--modes", "colour,material,logE",
                                  "--size", "96", "--device", "cpu", "-q"])
        png.unlink(missing_ok=True)
        if step("simulate", "simulate", ["simulate", str(annotated), "--out", str(sim_dir), "--frames", str(frames),
                                         "--device", "cpu", "-q"]).code == 0:
            step("render frames", "render", ["render", str(sim_dir), "--out", str(png), "--size", "96",
                                             "--device", "cpu", "-q"])
    for path in (source, annotated, png, folder / "out.prepare.json"):
        path.unlink(missing_ok=True)
    shutil.rmtree(sim_dir, ignore_errors=True)
    return outcomes


def fuzz_info_once(data: bytes, folder: Path, name: str = "m.ply") -> Outcome:
    """`pixie info --json` on one mutated file: an error (one line) or a finite, validated summary."""
    path = folder / name

    def make(f: Path) -> list[str]:
        path.write_bytes(data)
        return ["info", str(path), "--json"]

    case = Case("info", "mutation", make)
    outcome = run_case(case, folder, timeout_s=20)
    if outcome.problems == ["wrong success"]:  # a mutation may leave a perfectly valid splat
        from pixie_gs.splat import read_splat

        outcome.problems = []
        try:
            cloud = read_splat(path)
            cloud.validate()
            if not np.isfinite(cloud.covariances()).all():
                outcome.problems.append("wrong success: non-finite covariance")
        except Exception as exc:  # noqa: BLE001
            outcome.problems.append(f"wrong success: info ok but read fails ({type(exc).__name__})")
    path.unlink(missing_ok=True)
    return outcome

