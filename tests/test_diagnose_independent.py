"""pixie diagnose on measurements it did not make: units, registration, start-time offset, outlier
tracks, the solver-error floor and honest ambiguity.

The "measured" data here never come from pixie-gs's own solver: they are either the fixtures of
tests/data/independent/ (written by an MLS-MPM in Taichi, scripts/make_independent_tracks.py;
see the README there) or analytic motions built in the test (rigid tosses with and without
quadratic drag, integrated to 1e-10 by scipy).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pixie_gs.diagnose.ambiguity import ambiguous_with, separation_hint
from pixie_gs.diagnose.checks import check_geometry, fit_time_offset, outlier_tracks
from pixie_gs.diagnose.floor import SolverFloor
from pixie_gs.diagnose.locate import noise_sigma
from pixie_gs.diagnose.measured import tracks_from_arrays
from pixie_gs.diagnose.score import rank, score_candidate
from pixie_gs.diagnose.synthetic import add_outlier_tracks, in_millimetres, independent_toss_scene, two_part_block
from pixie_gs.errors import InputError

DATA = Path(__file__).parent / "data" / "independent"
FPS = 25.0


@pytest.fixture(scope="module")
def cloud():
    return two_part_block(n=2000, seed=0)  # the model the fixtures' tracked points belong to


def fixture(name: str) -> dict:
    with np.load(DATA / f"{name}.npz") as data:
        return {k: data[k] for k in data.files}


def test_fixtures_are_small_and_documented():
    meta = json.loads(str(fixture("nothing")["meta"]))
    assert meta["engine"].startswith("taichi") and meta["hidden"] == "nothing"
    assert (DATA / "README.md").read_text().count("taichi") >= 1
    for path in DATA.glob("*.npz"):
        assert path.stat().st_size < 60_000, path


# ---------------------------------------------------------------------------------- units
def test_millimetre_tracks_are_refused_with_a_hint(cloud):
    data = fixture("air_drag")
    tracks = tracks_from_arrays(data["t"], in_millimetres(data["x"]), cloud, source="drag_mm.npz")
    with pytest.raises(InputError) as err:
        check_geometry(tracks, cloud)
    msg = str(err.value)
    assert "drag_mm.npz" in msg and "--units mm" in msg and "not in the splat's units" in msg
    fixed, reg = check_geometry(tracks, cloud, units="mm")
    assert reg.units_factor == 1e-3 and 0.9 < reg.extent_ratio < 1.05
    assert reg.match_median < 0.5 * reg.gaussian_spacing  # re-matched after scaling
    assert np.allclose(fixed.x, data["x"], atol=1e-6)


def test_cli_refuses_mm_tracks_before_writing_anything(cloud, tmp_path, capsys):
    from pixie_gs.cli.main import main

    data = fixture("nothing")
    np.savez(tmp_path / "mm.npz", t=data["t"], x=in_millimetres(data["x"]))
    cloud.write(tmp_path / "model.ply")
    independent_toss_scene().to_json(tmp_path / "scene.json")
    out = tmp_path / "diag"
    code = main(["diagnose", str(tmp_path / "model.ply"), str(tmp_path / "mm.npz"), "--scene",
                 str(tmp_path / "scene.json"), "--out", str(out), "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "mm.npz" in err[0] and "--units mm" in err[0]
    assert not out.exists()


# ---------------------------------------------------------------------------------- registration
def test_rigid_registration_at_t0_is_fitted_and_applied(cloud):
    data = fixture("nothing")
    a = np.radians(6.0)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    moved = data["x"] @ R.T + np.array([0.03, -0.02, 0.01])
    tracks = tracks_from_arrays(data["t"], moved, cloud, source="moved.npz")
    fixed, reg = check_geometry(tracks, cloud)
    assert reg.registration_applied and reg.rotation_deg == pytest.approx(6.0, abs=0.5)
    assert reg.match_median < 0.5 * reg.gaussian_spacing
    assert np.mean(fixed.ids == tracks_from_arrays(data["t"], data["x"], cloud).ids) > 0.9
    # points of another (2.5× larger) object: no rigid motion puts them on the model → refused
    centre = data["x"][0].mean(0)
    other = centre + 2.5 * (data["x"] - centre)
    with pytest.raises(InputError, match="Gaussian spacing"):
        check_geometry(tracks_from_arrays(data["t"], other, cloud, source="s.npz"), cloud)


# ---------------------------------------------------------------------------------- start-time offset
def _toss(t: np.ndarray, release_s: float, drag_per_m: float, points: np.ndarray) -> np.ndarray:
    """Rigid toss of `points` (M,3): at rest until `release_s`, then v0 = (1.2, 0, 0.8) m/s under
    gravity and quadratic drag a = −k|v|v (scipy, rtol 1e-10); the ground is not reached."""
    from scipy.integrate import solve_ivp

    def rhs(_, y):
        v = y[3:]
        return np.r_[v, np.array([0.0, 0.0, -9.81]) - drag_per_m * np.linalg.norm(v) * v]

    tau = np.clip(t - release_s, 0.0, None)
    sol = solve_ivp(rhs, (0.0, float(tau.max()) + 1e-9), [0, 0, 0, 1.2, 0.0, 0.8], t_eval=np.unique(tau),
                    rtol=1e-10, atol=1e-12)
    disp = sol.y[:3].T[np.searchsorted(np.unique(tau), tau)]
    return points[None] + disp[:, None, :]


@pytest.mark.parametrize("shift_frames", [1.0, -1.0, 0.5])
def test_start_time_offset_is_recovered_despite_a_missing_effect(shift_frames):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.1, 0.1, (40, 3)) + [0, 0, 1.0]
    t = np.arange(17) / FPS
    model_frames = _toss(np.arange(30) / FPS, 0.0, 0.0, pts)          # the model: no drag, release at 0
    # the truth has drag (up to 1 m/s² here: a missing effect the offset must not absorb) and is released at measured time δ (δ < 0: the camera started late)
    measured = _toss(t, shift_frames / FPS, 0.5, pts) + rng.normal(0.0, 1e-3, (17, 40, 3))
    delta, best, zero = fit_time_offset(model_frames, FPS, measured, np.ones((17, 40), bool), t)
    assert delta * FPS == pytest.approx(shift_frames, abs=0.2)
    assert best < 0.5 * zero


# ---------------------------------------------------------------------------------- outliers
def test_outlier_tracks_are_found_from_the_neighbours(cloud):
    truth, model = fixture("part_density"), fixture("nothing")   # model = the same scene without the effect
    ids = truth["source_ids"]
    bad_x, bad = add_outlier_tracks(truth["x"], 0.05, seed=6)
    r = bad_x - model["x"]
    visible = np.ones(r.shape[:2], bool)
    found, z = outlier_tracks(r, visible, cloud.means[ids].astype(np.float64), cloud.get("part_id")[ids],
                              noise_sigma(r, visible))
    assert set(np.nonzero(found)[0]) == set(bad.tolist())
    # the clean residual — a real, large, part-dependent effect — has no outliers
    clean, _ = outlier_tracks(truth["x"] - model["x"], visible, cloud.means[ids].astype(np.float64),
                              cloud.get("part_id")[ids], noise_sigma(truth["x"] - model["x"], visible))
    assert not clean.any()


# ---------------------------------------------------------------------------------- solver-error floor
def test_floor_enters_the_score_and_the_verdict():
    n, sigma, f = 5100, 1e-3, 0.01
    base = n * (sigma ** 2 + f ** 2) * 1.6     # a gap only a little above noise + solver error
    cand = base - 1.5 * n * f ** 2             # removes 1.5 n f²: solver error could do that
    assert score_candidate("x", None, {}, 1, cand, base, n, sigma).significant
    assert not score_candidate("x", None, {}, 1, cand, base, n, sigma, floor_sigma=f).significant
    fl = SolverFloor(rms=0.015, grid=28, dx_m=0.05, fine_grid=35, coarse_grid=22, world_scale=1.5, gap_rms=0.02)
    assert not fl.converged and "not converged at dx = 5 cm" in fl.message() and "--grid 56" in fl.message()
    assert SolverFloor(0.015, 56, 0.025, 70, 44, 1.5, 0.1).converged


def test_nothing_hidden_on_a_coarse_grid_is_called_solver_error(cloud):
    from pixie_gs.diagnose.pipeline import diagnose
    from pixie_gs.diagnose.report import status

    data = fixture("nothing")
    tracks = tracks_from_arrays(data["t"], data["x"], cloud, source="nothing.npz")
    d = diagnose(cloud, independent_toss_scene(grid=40), tracks, device="cpu")
    assert d.effect is None and not d.converged
    assert d.floor.rms > 0.5 * d.floor.gap_rms          # the solver's own error is most of the gap
    assert status(d).startswith("not converged at dx = 5 cm") and "--grid" in status(d)


# ---------------------------------------------------------------------------------- ambiguity
def _fit_1d(t, x, model, lo, hi):
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(lambda p: float(np.sum((x - model(t, p)[:, None]) ** 2)), bounds=(lo, hi),
                          method="bounded", options={"xatol": 1e-8})
    return res.x, float(res.fun)


@pytest.mark.parametrize("speed, floor, expect_ambiguous", [(1.2, 0.01, True), (12.0, 0.0, False)])
def test_drag_and_damping_are_ambiguous_at_low_speed_only(speed, floor, expect_ambiguous):
    """Analytic: a point moving along x with quadratic drag, x = ln(1 + k v0 t)/k, measured by
    50 tracks with 1 mm noise; fitted by drag and by linear damping x = v0 (1 − e^(−ct))/c."""
    rng = np.random.default_rng(2)
    t = np.arange(17) / FPS
    k = 0.8
    x = (np.log1p(k * speed * t) / k)[:, None] + rng.normal(0.0, 1e-3, (17, 50))
    drag = lambda tt, kk: np.log1p(kk * speed * tt) / kk  # noqa: E731
    damp = lambda tt, c: speed * (1.0 - np.exp(-c * tt)) / c  # noqa: E731
    n = x.size * 3                                      # as if 3 coordinates, 2 of them exact
    base = float(np.sum((x - (speed * t)[:, None]) ** 2))
    k_fit, sse_drag = _fit_1d(t, x, drag, 1e-3, 10.0)
    _, sse_damp = _fit_1d(t, x, damp, 1e-3, 50.0)
    sigma = 1e-3 / np.sqrt(3.0)
    scored = rank([score_candidate("air_drag", None, {"k_per_m": k_fit}, 1, sse_drag, base, n, sigma, floor_sigma=floor),
                   score_candidate("viscous_damping", None, {}, 1, sse_damp, base, n, sigma, floor_sigma=floor)])
    assert scored[0].effect == "air_drag" and scored[0].significant
    amb = ambiguous_with(scored, n, len(t), floor)
    assert bool(amb) == expect_ambiguous
    if expect_ambiguous:
        assert amb[0].effect == "viscous_damping"
        assert "speed" in separation_hint("air_drag", "viscous_damping")


# ---------------------------------------------------------------------------------- end to end
def test_cli_on_independent_drag_reports_floor_ambiguity_and_effective_values(cloud, tmp_path, capsys):
    """The command on the independent engine's drag fixture (no ids, 1 mm noise): the hidden drag
    is named first or as indistinguishable, with the floor, the checks and the effective-value note."""
    from pixie_gs.cli.main import main

    data = fixture("air_drag")
    np.savez(tmp_path / "m.npz", t=data["t"], x=data["x"])
    cloud.write(tmp_path / "model.ply")
    independent_toss_scene().to_json(tmp_path / "scene.json")
    out = tmp_path / "diag"
    code = main(["diagnose", str(tmp_path / "model.ply"), str(tmp_path / "m.npz"), "--scene", str(tmp_path / "scene.json"),
                 "--out", str(out), "--effects", "air_drag,viscous_damping", "--max-effects", "1",
                 "--max-evals", "4", "--no-rrd", "--json", "--device", "cpu", "--quiet"])
    assert code == 0
    s = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert s["converged"] and s["floor"]["enabled"] and 0 < s["floor"]["rms_mm"] < 60
    named = {s["effect"]} | {a["effect"] for a in s["ambiguous_with"]}
    assert "air_drag" in named
    if s["ambiguous_with"]:
        assert "indistinguishable" in s["status"] and all(a["separate_by"] for a in s["ambiguous_with"])
        assert all(a["effect"] in s["status"] for a in s["ambiguous_with"])
    assert "effective for this solver" in s["note"]
    assert s["registration"]["units_factor"] == 1.0 and not s["registration"]["outliers"]
    assert s["gap_after"] < 0.3 * s["gap_before"]
    report = json.loads((out / "report.json").read_text())
    assert report["floor"]["gap_rms"] == pytest.approx(s["gap_before"])


def test_checks_simulate_the_re_matched_gaussians_after_a_registration(cloud):
    """prepare_tracks runs the geometry checks beside the model-as-given simulation of the tracked
    Gaussians; when the registration re-matches the points to other Gaussians, that simulation is
    made again for them: the baseline it primes is the simulation of the points as finally matched."""
    from pixie_gs.diagnose.forward import sample_at, sim_schedule
    from pixie_gs.diagnose.pipeline import DiagnoseOptions, prepare_tracks
    from pixie_gs.sim.run import simulate

    data = fixture("nothing")
    a = np.radians(6.0)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    scene = independent_toss_scene(40)
    options = DiagnoseOptions(batch=False)
    for x, registered in ((data["x"], False), (data["x"] @ R.T + np.array([0.03, -0.02, 0.01]), True)):
        tracks = tracks_from_arrays(data["t"], x, cloud, source="t.npz")
        log: list = []
        checked, reg, primed = prepare_tracks(tracks, cloud, scene, "cpu", options, log)
        assert reg.registration_applied == registered
        assert len(log) == (2 if registered else 1)
        assert registered == (not np.array_equal(checked.ids, tracks.ids))
        frames, fps = sim_schedule(checked.t)
        alone = simulate(cloud, scene, frames, fps, device="cpu", quiet=True).x[:, checked.ids].astype(np.float64)
        np.testing.assert_array_equal(primed, sample_at(alone, fps, checked.t))
