"""Fuzzing (issue 15): property-based tests of the splat readers, the scene parser and the measured
tracks reader, plus a sample of the bad-input corpus through every command (tests/fuzz_corpus.py).

The promise checked everywhere: a reader returns a valid object or raises InputError (one line);
never another exception, never a hang. The long mode is benchmarks/bench_fuzz.py.
"""
from __future__ import annotations

import io
import json
import math
import shutil
import struct
import warnings

import numpy as np
import pytest
from fuzz_corpus import (MESH_SUFFIXES_FUZZED, SPLAT_SUFFIXES, through_the_pipeline_once, corpus,
                         fuzz_convert_once, fuzz_info_once, mutate, mutate_mesh, mutate_splat, run_case, scene_dict,
                         valid_mesh_bytes, valid_ply_bytes, valid_splat_bytes, vertex_table)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pixie_gs.errors import InputError
from pixie_gs.splat import SplatCloud, read_splat

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                         HealthCheck.too_slow])
GOOD_PLY = valid_ply_bytes(30, materials=True)


def _read_or_input_error(path) -> SplatCloud | None:
    try:
        cloud = read_splat(path)
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc), str(exc)
        return None
    # anything read must be fully valid: finite covariances, no absurd values
    cloud.validate()
    assert len(cloud) > 0 and np.isfinite(cloud.covariances()).all()
    return cloud


# ------------------------------------------------------------------------- splat readers
@FUZZ
@given(st.data())
def test_mutated_ply_is_read_validly_or_refused_in_one_line(tmp_path, data):
    seed = data.draw(st.integers(0, 2**32 - 1))
    blob = GOOD_PLY
    for _ in range(data.draw(st.integers(1, 3))):
        blob = mutate(blob, np.random.default_rng(seed))
        seed += 1
    path = tmp_path / "m.ply"
    path.write_bytes(blob)
    _read_or_input_error(path)


VALID_SPLATS = {suffix: valid_splat_bytes(suffix) for suffix in SPLAT_SUFFIXES}


@pytest.mark.parametrize("suffix", SPLAT_SUFFIXES)
@FUZZ
@given(data=st.data())
def test_mutated_splat_of_every_format_is_read_validly_or_refused_in_one_line(tmp_path, suffix, data):
    """Header-aware mutations for the PLY formats; for .spz mostly of the inflated stream, deflated again."""
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    blob = VALID_SPLATS[suffix]
    for _ in range(data.draw(st.integers(1, 3))):
        blob = mutate_splat(blob, suffix, rng)
    path = tmp_path / f"m.{suffix}"
    path.write_bytes(blob)
    _read_or_input_error(path)


@FUZZ
@given(st.binary(max_size=2000), st.sampled_from([".ply", ".splat", ".spz", ".compressed.ply", ""]))
def test_arbitrary_bytes_with_any_splat_suffix(tmp_path, blob, suffix):
    path = tmp_path / f"f{suffix}"
    path.write_bytes(blob)
    _read_or_input_error(path)


@FUZZ
@given(st.lists(st.floats(width=32, allow_nan=True, allow_infinity=True), min_size=32, max_size=32),
       st.integers(0, 31))
def test_any_float_values_in_one_gaussian(tmp_path, values, which):
    """Every float32 bit pattern class (NaN, ±inf, subnormal, huge) in any property of one Gaussian."""
    t = vertex_table(8, materials=False)
    names = list(t.dtype.names)
    for name, v in zip(names, values):
        t[name][which % 8] = v
    from fuzz_corpus import write_ply

    _read_or_input_error(write_ply(tmp_path / "v.ply", t))


@FUZZ
@given(st.binary(min_size=0, max_size=32 * 6))
def test_antimatter_splat_records(tmp_path, blob):
    """.splat is 32-byte records (position, scale float32; rgba, rotation uint8): any bytes."""
    path = tmp_path / "x.splat"
    path.write_bytes(blob)
    _read_or_input_error(path)


# ------------------------------------------------------------------------- scene parser
JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=8), kids, max_size=4),
                    max_leaves=20)
SCENE_KEYS = ["up", "object", "domain", "gravity", "ground", "walls", "damping", "air_drag", "wind", "impulses",
              "fixed", "part_overrides", "solver", "materials"]


@FUZZ
@given(st.dictionaries(st.sampled_from(SCENE_KEYS), JSON, max_size=5))
def test_scene_parser_accepts_or_refuses_any_json(tmp_path, data):
    from pixie_gs.sim.scene import Scene

    merged = {**scene_dict(), **data}
    try:
        scene = Scene.from_dict(merged, source="s.json")
    except InputError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("s.json: ")
        return
    assert all(math.isfinite(v) for v in scene.domain_size) and scene.dx > 0
    assert all(math.isfinite(v) for v in scene.gravity)


@FUZZ
@given(st.binary(max_size=300))
def test_scene_file_of_any_bytes(tmp_path, blob):
    from pixie_gs.sim.scene import Scene

    path = tmp_path / "s.json"
    path.write_bytes(blob)
    try:
        Scene.from_json(path)
    except InputError as exc:
        assert "\n" not in str(exc)


@FUZZ
@given(st.sampled_from(["size_m", "grid"]), st.one_of(st.integers(-10**30, 10**30), st.floats(), st.text(max_size=3)))
def test_scene_domain_numbers(tmp_path, key, value):
    from pixie_gs.sim.scene import Scene

    try:
        scene = Scene.from_dict({"domain": {key: value}}, source="s.json")
    except InputError:
        return
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an accepted scene computes its grid without a floating-point warning
        dims = scene.grid_dims
    assert all(d > 0 for d in dims) and math.prod(dims) < 10**11


# ------------------------------------------------------------------------- measured tracks
@FUZZ
@given(st.integers(0, 6), st.integers(0, 25),
       st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=8),
       st.booleans(), st.booleans())
def test_measured_tracks_reader(tmp_path, frames, points, times, with_ids, with_visible):
    from pixie_gs.diagnose.measured import load_measured

    rng = np.random.default_rng(frames * 31 + points)
    t = np.resize(np.asarray(times, np.float64), frames)
    arrays = {"t": t, "x": rng.uniform(-0.5, 0.5, (frames, points, 3))}
    if with_ids:
        arrays["ids"] = rng.integers(-2, 60, points)
    if with_visible:
        arrays["visible"] = rng.random((frames, points)) < 0.8
    path = tmp_path / "m.npz"
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    cloud = SplatCloud.from_arrays(rng.uniform(-0.5, 0.5, (50, 3)))
    try:
        tracks = load_measured(path, cloud)
    except InputError as exc:
        assert "\n" not in str(exc)
        return
    assert np.isfinite(tracks.t).all() and (np.diff(tracks.t) > 0).all() and tracks.num_points >= 10


# ------------------------------------------------------------------------- the corpus, a CI sample
CASES = corpus(seed=0)
SAMPLE = [c for cmd in sorted({c.command for c in CASES})  # every command, a spread of its cases
          for c in [c for c in CASES if c.command == cmd][::9]]


def test_sample_covers_every_command():
    from pixie_gs.cli.main import COMMANDS

    assert len(CASES) >= 300
    assert {c.command for c in SAMPLE} == set(COMMANDS)


@pytest.mark.parametrize("case", SAMPLE, ids=lambda c: f"{c.command}-{c.name}")
def test_bad_input_corpus(tmp_path, case):
    outcome = run_case(case, tmp_path / "case", timeout_s=60)
    assert outcome.problems == [], (case.command, case.name, outcome.problems)


def test_mutation_fuzz_through_info(tmp_path):
    rng = np.random.default_rng(1234)
    folder = tmp_path / "m"
    folder.mkdir()
    failures = []
    for _ in range(150):
        blob = mutate(GOOD_PLY, rng)
        outcome = fuzz_info_once(blob, folder)
        if outcome.problems:
            failures.append(outcome.problems)
    assert failures == []


@pytest.mark.parametrize("suffix", MESH_SUFFIXES_FUZZED)
def test_mutation_fuzz_through_convert(tmp_path, suffix):
    """Meshes as trimesh writes them, mutated: `pixie convert` refuses in one line or writes a valid splat.
    Before the index and shape checks of convert.load_mesh, 167 of 1,000 GLB and 112 of 1,000 PLY meshes
    mutated this way ended in a traceback (docs/benchmarks.md, stop 53)."""
    rng = np.random.default_rng([1234, len(suffix)])
    base = valid_mesh_bytes(suffix)
    failures = []
    for _ in range(80):
        blob = base
        for _ in range(int(rng.integers(1, 4))):
            blob = mutate_mesh(blob, suffix, rng)
        outcome = fuzz_convert_once(blob, suffix, tmp_path)
        if outcome.problems:
            failures.append(outcome.problems)
    assert failures == []


def test_valid_mutated_splats_annotate_render_and_simulate_or_fail_in_one_line(tmp_path):
    """Mutated splats that still read as valid go through annotate, render, a 3-frame simulate and render of
    its frames: finite results or one line (exit 1 or 3), never a crash (stop 53: a NaN annotate and a segfault
    came from such files; the long run, meshes included, is `bench_fuzz.py --pipeline N`)."""
    rng = np.random.default_rng(53)
    bases = {suffix: valid_splat_bytes(suffix) for suffix in SPLAT_SUFFIXES}
    done, failures, steps = 0, [], set()
    while done < 6:
        suffix = SPLAT_SUFFIXES[done % len(SPLAT_SUFFIXES)]
        blob = mutate_splat(bases[suffix], suffix, rng)
        path = tmp_path / f"probe.{suffix}"
        path.write_bytes(blob)
        if _read_or_input_error(path) is None:
            continue
        path.unlink()
        done += 1
        outcomes = through_the_pipeline_once(blob, suffix, tmp_path)
        failures += [(suffix, step, o.problems) for step, o in outcomes.items() if o.problems]
        steps.update(outcomes)
    assert failures == []
    assert set(steps) == {"annotate", "render", "simulate", "render frames"}  # every step ran at least once
