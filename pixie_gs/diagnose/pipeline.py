"""The discrepancy loop: simulate → locate → fit & score candidate effects → add the winner → repeat.

Round 1 screens every (effect, part) candidate around the given model (see fit.py), verifies
and refines the most promising, and ranks all by ΔBIC (score.py). The winner, if significant,
is added to the model and a new round tests for a second effect on top of it, re-using the
round-1 sensitivities to predict each candidate's gain (no new probe runs), until nothing
significant is left or `max_effects` effects were added.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..materials import STATIONARY
from ..progress import stage
from ..splat import SplatCloud
from .effects import Effect, get_effect, registry
from .fit import Candidate, Problem, drop_predictions, make_candidates, predict_linear, refine_all, screen_all, verify_all
from .forward import Fidelity, ForwardModel, SimRecord
from .locate import Location, locate, residuals, rms_gap, spatial_clusters
from .ambiguity import ambiguous_with
from .checks import Registration, check_geometry, fit_time_offset, outlier_tracks
from .floor import SolverFloor, estimate_floor
from .measured import MeasuredTracks
from .score import BIC_THRESHOLD, MIN_EXCESS_EXPLAINED, Scored, can_be_significant, rank, score_candidate


OFFSET_SEARCH_FRAMES = 3.0      # start-time offsets searched: ± this many frames
RIVAL_WITHIN = 0.1              # reduced model: rivals within 10 % of the winner's ΔBIC are settled on the full model
MAX_RIVALS = 2
MAX_CORRECTIONS = 3             # full-model secant corrections of an effect fitted on the reduced model
OFFSET_MAX_LOSS_RATIO = 0.3     # an applied offset must cut the early frames' Huber loss by 70 %


@dataclass
class DiagnoseOptions:
    """Knobs of the loop (defaults sized for a 2-core CPU; see docs/diagnose.md)."""

    effects: list[str] | None = None      # None: the whole library
    max_effects: int = 2                  # length of the chain of added effects
    max_parts: int = 3                    # per-part effects are tried on the worst this-many parts
    verify_top: int = 4                   # candidates simulated at their linear prediction
    refine_top: int = 2                   # candidates refined to `max_evals` runs
    refine_max: int = 4                   # ... plus close rivals (within refine_within × the best SSE)
    refine_within: float = 4.0
    max_evals: int = 10                   # runs per candidate (screen + verify + refine)
    min_refine_explained: float = 0.1     # refine only candidates explaining this share of the excess gap
    bic_threshold: float = BIC_THRESHOLD
    min_excess_explained: float = MIN_EXCESS_EXPLAINED
    fidelity: Fidelity = field(default_factory=Fidelity)
    fill: bool = False                    # fill closed objects' interiors (as `pixie simulate --fill`)
    checks: bool = True                   # units, registration, start-time offset, outlier tracks (checks.py)
    units: str | None = None              # unit of the measured coordinates (mm|cm|m; None: the splat's)
    solver_floor: bool = True             # estimate the solver-error floor (floor.py) and use it in the score
    batch: bool | None = None             # candidate runs as one batched simulation (None: on a GPU only)


@dataclass
class RoundResult:
    index: int
    baseline_sse: float
    baseline_rms: float
    location: Location
    ranking: list[Scored]
    chosen: Scored | None
    note: str | None = None   # why the round made no runs, when it could not name anything


@dataclass
class Diagnosis:
    """Everything the report needs: rounds, the accepted chain, the improved model, the gap."""

    rounds: list[RoundResult]
    accepted: list[Scored]
    scene: object
    cloud: SplatCloud
    tracks: MeasuredTracks
    base_pred: np.ndarray
    final_pred: np.ndarray
    noise_sigma: float
    runs: int
    sim_seconds: float
    cache_hits: int
    parts_from_materials: bool = False
    registration: Registration | None = None
    floor: SolverFloor | None = None
    ambiguous: list[Scored] = field(default_factory=list)
    sim_batches: int = 0  # batched simulations among `runs` (each counted per variant in runs)
    sim_log: list[SimRecord] = field(default_factory=list)  # every simulation, the checks' included

    @property
    def converged(self) -> bool:
        return self.floor is None or self.floor.converged

    @property
    def gap_before(self) -> float:
        return rms_gap(residuals(self.tracks.x, self.base_pred, self.tracks.visible), self.tracks.visible)

    @property
    def gap_after(self) -> float:
        return rms_gap(residuals(self.tracks.x, self.final_pred, self.tracks.visible), self.tracks.visible)

    @property
    def effect(self) -> Scored | None:
        return self.accepted[0] if self.accepted else None


def working_cloud(cloud: SplatCloud) -> tuple[SplatCloud, bool]:
    """The cloud with a `part_id` (material classes stand in for parts when it has none)."""
    if cloud.has("part_id"):
        return cloud, False
    out = cloud.copy()
    mid = cloud.get("material_id") if cloud.has("material_id") else np.zeros(len(cloud), np.int32)
    out.set("part_id", mid.astype(np.int32), np.int32)
    return out, True


def movable_parts(cloud: SplatCloud, scene) -> set[int]:
    """Parts with at least one particle the solver moves (not stationary, not held fixed)."""
    part = cloud.get("part_id")
    mid = cloud.get("material_id") if cloud.has("material_id") else np.zeros(len(cloud), np.int32)
    held = {p for p, o in scene.part_overrides.items() if o.fixed}
    for spec in scene.fixed:
        held |= set(spec.part_ids)
    return {int(p) for p in np.unique(part) if int(p) not in held and np.any(mid[part == p] != STATIONARY)}


def evidence(problem: Problem, pred: np.ndarray, labels: dict[str, np.ndarray], t: np.ndarray) -> dict:
    """The residual signature a fit explains: share of the squared gap removed per region and
    the times where it removes most."""
    r_after = residuals(problem.measured_x, pred, problem.visible)
    before, after = np.square(problem.r0), np.square(r_after)
    out: dict = {}
    for kind, lab in labels.items():
        shares = {}
        for key in np.unique(lab):
            b = float(before[:, lab == key].sum())
            if b > 0:
                shares[str(int(key))] = round(1.0 - float(after[:, lab == key].sum()) / b, 4)
        out[f"explained_by_{kind}"] = shares
    gain = before.sum(axis=(1, 2)) - after.sum(axis=(1, 2))
    top = np.argsort(-gain)[:3]
    out["most_explained_at_s"] = [round(float(t[i]), 4) for i in sorted(top) if gain[i] > 0]
    return out


class _Runner:
    """Shared state of one diagnosis: the forward model, options and progress display."""

    def __init__(self, model: ForwardModel, tracks: MeasuredTracks, options: DiagnoseOptions,
                 effects: list[Effect]) -> None:
        self.model = model
        self.tracks = tracks
        self.options = options
        self.effects = effects
        self.sigma = float("inf")
        self.floor_c = 0.0                       # solver-error floor per coordinate (floor.py)
        self.original_sse: float | None = None  # SSE of the model as given (set in round 1)

    def score(self, problem: Problem, cand: Candidate, labels: dict, n: int) -> Scored | None:
        best = cand.best
        if best is None:
            return None
        s = score_candidate(cand.effect.name, cand.part, dict(best.values), len(cand.params), best.sse,
                            problem.base_sse, n, self.sigma, cand.runs, self.options.bic_threshold,
                            self.options.min_excess_explained, self.original_sse, floor_sigma=self.floor_c)
        if best.pred is not None:
            s.evidence = evidence(problem, best.pred, labels, self.tracks.t)
        return s

    def excess_share(self, problem: Problem, sse: float | None, n: int) -> float:
        if sse is None or not np.isfinite(sse):
            return 0.0
        excess = max(problem.base_sse - n * (self.sigma ** 2 + self.floor_c ** 2), 1e-300)
        return (problem.base_sse - sse) / excess

    def run_round(self, index: int, problem: Problem, cloud: SplatCloud, scene,
                  previous: list[Candidate] | None, exclude: set[tuple[str, int | None]]
                  ) -> tuple[RoundResult, list[Candidate], dict[tuple, Candidate]]:
        tracks, opts = self.tracks, self.options
        if self.original_sse is None:
            self.original_sse = problem.base_sse
        loc = locate(problem.r0, tracks.visible, cloud, tracks.ids)
        self.sigma = min(self.sigma, loc.noise_sigma) if loc.noise_sigma > 0 else self.sigma
        if not np.isfinite(self.sigma):
            self.sigma = 0.0
        n = tracks.num_observations
        if index > 1 and not can_be_significant(problem.base_sse, n, self.sigma, self.original_sse, self.floor_c,
                                                min_excess_explained=opts.min_excess_explained):
            note = ("no runs: the gap left is too small for any further effect to be significant (it must "
                    "remove a share of the above-noise gap of the model as given, more than solver error "
                    "could fake)")
            stage(f"round {index}: RMS gap {loc.rms:.4g}; nothing significant can be left: {note}")
            return RoundResult(index, problem.base_sse, loc.rms, loc, [], None, note), [], {}
        movable = movable_parts(cloud, scene)
        parts = [p for p in loc.ranked_parts() if p in movable][: opts.max_parts]
        labels = {"part": cloud.get("part_id")[tracks.ids],
                  "cluster": spatial_clusters(cloud.means[tracks.ids].astype(np.float64), 4)}
        cands = [c for c in make_candidates(self.effects, scene, cloud, parts)
                 if (c.effect.name, c.part) not in exclude]
        stage(f"round {index}: RMS gap {loc.rms:.4g} (noise σ ≈ {self.sigma:.2g} per axis); "
              f"worst part {parts[0] if parts else '-'}; {len(cands)} candidates")
        self.model.stage = f"screen {index}"
        if previous is None:
            screen_all(problem, cands, desc=f"screen (round {index})")
        else:
            old = {(c.effect.name, c.part): c for c in previous}
            r_flat = problem.flat(problem.r0)
            to_screen, reruns = [], []
            for cand in cands:
                prior = old.get((cand.effect.name, cand.part))
                if prior is not None and prior.jacobian is not None:
                    cand.jacobian = prior.jacobian
                    predict_linear(problem, cand, r_flat, cand.off_values())
                elif prior is not None and prior.best is not None and prior.base_sse is not None \
                        and prior.best.sse < prior.base_sse:
                    # no sensitivity (threshold / switch effects) but it helped before: one run
                    # at its earlier best on top of the new model
                    reruns.append((cand, prior.best.values))
                elif prior is None:
                    to_screen.append(cand)  # a part that was not among the worst before
            if to_screen or reruns:
                screen_all(problem, to_screen, extra=reruns, desc=f"screen (round {index})")

        def estimate(c: Candidate) -> float:
            vals = [e.sse for e in c.evaluations] + ([c.predicted_sse] if c.predicted_sse is not None else [])
            return min(vals) if vals else float("inf")

        cands.sort(key=estimate)
        self.model.stage = f"verify {index}"
        verify_all(problem, cands[: opts.verify_top], desc=f"verify (round {index})")
        cands.sort(key=lambda c: c.best.sse if c.best else float("inf"))
        # the top `refine_top`, plus runner-ups whose verified fit is within REFINE_WITHIN × the best
        # SSE (up to `refine_max`): an ambiguity verdict needs every close rival fitted as well
        best_sse = cands[0].best.sse if cands and cands[0].best else float("inf")
        close = [c for c in cands[opts.refine_top: opts.refine_max]
                 if c.best is not None and c.best.sse <= opts.refine_within * best_sse]
        promising = [c for c in cands[: opts.refine_top] + close
                     if c.best is not None and c.best.sse < problem.base_sse
                     and score_candidate(c.effect.name, c.part, {}, len(c.params), c.best.sse, problem.base_sse,
                                         n, self.sigma).delta_bic > 0
                     and self.excess_share(problem, c.best.sse, n) >= opts.min_refine_explained]
        self.model.stage = f"refine {index}"
        refine_all(problem, promising, opts.max_evals, desc=f"refine (round {index})")
        scored = [s for s in (self.score(problem, c, labels, n) for c in cands) if s is not None]
        ranking = rank(scored)
        chosen = ranking[0] if ranking and ranking[0].significant else None
        by_key = {(c.effect.name, c.part): c for c in cands}
        for c in cands:
            if chosen is None or (c.effect.name, c.part) != (chosen.effect, chosen.part):
                drop_predictions(c)
        result = RoundResult(index, problem.base_sse, loc.rms, loc, ranking, chosen)
        if chosen:
            stage(f"round {index}: best {chosen.label} {chosen.params} explains "
                  f"{100 * chosen.explained:.0f}% of the squared gap (ΔBIC {chosen.delta_bic:.1f})")
        else:
            best = ranking[0] if ranking else None
            stage(f"round {index}: nothing significant is missing"
                  + (f" (best {best.label}: ΔBIC {best.delta_bic:.1f}, "
                     f"{100 * best.excess_explained:.0f}% of the above-noise gap)" if best else ""))
        return result, cands, by_key


def diagnose(cloud: SplatCloud, scene, tracks: MeasuredTracks, device: str = "auto",
             options: DiagnoseOptions | None = None, cache: dict | None = None) -> Diagnosis:
    """Find, fit and add the effects the model (cloud + scene) is missing versus `tracks`.

    numpy's BLAS runs on one thread meanwhile (batch/worker_env.blas_threads): the fit's matrix
    work is a few columns at a time, and a pool sized to every core only spins between calls."""
    from ..batch.worker_env import blas_threads

    with blas_threads(1):
        return _diagnose(cloud, scene, tracks, device, options, cache)


def _diagnose(cloud: SplatCloud, scene, tracks: MeasuredTracks, device: str, options: DiagnoseOptions | None,
              cache: dict | None) -> Diagnosis:
    options = options or DiagnoseOptions()
    effects = list(registry().values()) if not options.effects else [get_effect(n) for n in options.effects]
    if not effects:
        raise InputError("no candidate effects to test")
    work, from_materials = working_cloud(cloud)
    registration = None
    primed = None
    checks_log: list[SimRecord] = []
    if options.batch is None:  # batched simulation on a GPU only (forward.py)
        from ..devices import resolve_warp_device

        options = copy.copy(options)
        options.batch = resolve_warp_device(device) != "cpu"
    if options.checks:
        tracks, registration, primed = prepare_tracks(tracks, work, scene, device, options, checks_log)
    model = ForwardModel(work, tracks, device=device, fill=options.fill, fidelity=options.fidelity, cache=cache,
                         batch=options.batch)
    if primed is not None:
        model.prime(scene, work, primed)
    if model.is_reduced:
        stage(f"fitting on a reduced model: {len(model.keep)} of {len(work)} Gaussians, "
              f"grid × {model.grid_scale:g} (delta-corrected against the full model)")
    model.log[:0] = checks_log
    runner = _Runner(model, tracks, options, effects)
    model.stage = "baseline"
    stage("simulating the model as given")
    base_pred = model.set_baseline(scene, work)
    stage(f"solver-error floor: re-running the model as given on a finer grid" if options.solver_floor else
          "solver-error floor: off")
    model.stage = "floor"
    floor = estimate_floor(model, scene, work, base_pred, tracks, enabled=options.solver_floor)
    runner.floor_c = floor.per_coordinate
    if floor.enabled:
        stage(f"solver-error floor {floor.rms:.3g} (grid {floor.grid} vs {floor.fine_grid}, {floor.coarse_grid}) next to the gap "
              f"{floor.gap_rms:.3g} (splat units)")
    if floor.enabled and floor.converged and floor.gap_rms < 4.0 * floor.rms:
        stage(f"warning: the gap is only {floor.gap_rms / floor.rms:.1f}× the solver-error floor; "
              f"a finer grid (--grid {floor.suggested_grid()}) would make the diagnosis firmer")
    if not floor.converged:
        stage(floor.message())
        r0 = residuals(tracks.x, base_pred, tracks.visible)
        loc = locate(r0, tracks.visible, work, tracks.ids)
        rnd = RoundResult(1, float(np.sum(r0 ** 2)), loc.rms, loc, [], None)
        return Diagnosis([rnd], [], copy.deepcopy(scene), work, tracks, base_pred, base_pred, loc.noise_sigma,
                         model.runs, model.seconds, model.cache_hits, from_materials, registration, floor,
                         sim_batches=model.batches, sim_log=model.log)
    cur_scene, cur_cloud, cur_pred = scene, work, base_pred
    rounds: list[RoundResult] = []
    accepted: list[Scored] = []
    previous: list[Candidate] | None = None
    exclude: set[tuple[str, int | None]] = set()
    for index in range(1, options.max_effects + 2):
        problem = Problem(model, cur_scene, cur_cloud, tracks.x, tracks.visible, cur_pred)
        result, cands, by_key = runner.run_round(index, problem, cur_cloud, cur_scene, previous, exclude)
        rounds.append(result)
        chosen = result.chosen
        if chosen is None or len(accepted) >= options.max_effects:
            if chosen is not None:
                result.chosen = None  # chain is full: report but do not add
            break
        exclude.add((chosen.effect, chosen.part))
        winner = by_key[(chosen.effect, chosen.part)]
        before_scene, before_cloud = cur_scene, cur_cloud
        cur_scene, cur_cloud = winner.effect.apply(cur_scene, cur_cloud, winner.part, dict(chosen.params))
        if model.is_reduced:
            stage("re-simulating the full model with the added effect")
            model.stage = f"polish {index}"
            exclude.discard((chosen.effect, chosen.part))
            winner, (cur_scene, cur_cloud, cur_pred, chosen) = _settle_on_full_model(
                runner, problem, result, by_key, before_scene, before_cloud)
            exclude.add((chosen.effect, chosen.part))
            result.chosen = chosen
            accepted.append(chosen)
        else:
            accepted.append(chosen)
            model.stage = f"add {index}"
            cur_pred = winner.best.pred if winner.best and winner.best.pred is not None \
                else model.simulate_full(cur_scene, cur_cloud)
            model.set_baseline(cur_scene, cur_cloud, full_prediction=cur_pred)
        previous = [c for c in (previous or []) if (c.effect.name, c.part) not in by_key] + cands
        if len(accepted) >= options.max_effects:
            break
    ambiguous: list[Scored] = []
    if rounds and rounds[0].ranking and rounds[0].chosen is not None:
        ambiguous = ambiguous_with(rounds[0].ranking, tracks.num_observations, tracks.num_frames, runner.floor_c)
        if ambiguous:
            stage(f"{rounds[0].chosen.label} is indistinguishable on these data from "
                  f"{', '.join(a.label for a in ambiguous)}")
    return Diagnosis(rounds, accepted, copy.deepcopy(cur_scene), cur_cloud, tracks, base_pred, cur_pred,
                     runner.sigma, model.runs, model.seconds, model.cache_hits, from_materials, registration,
                     floor, ambiguous, model.batches, model.log)


def prepare_tracks(tracks: MeasuredTracks, cloud: SplatCloud, scene, device: str, options: DiagnoseOptions,
                   log: list[SimRecord] | None = None) -> tuple[MeasuredTracks, Registration, np.ndarray]:
    """Registration and sanity before physics (checks.py): units, rigid registration at t₀, match
    distances; then, from ONE simulation of the model as given, the start-time offset and the
    outlier tracks → (checked tracks, what was found, their baseline prediction for the cache).
    The simulation is appended to `log`.

    The geometry checks (host work: nearest neighbours, ICP) run on a worker thread while that
    simulation runs — it needs only the tracked Gaussians, which the checks change only when they
    re-match the points (units or registration applied to tracks without ids): then it runs again."""
    from concurrent.futures import ThreadPoolExecutor

    from .forward import sample_at, sim_schedule
    from .locate import noise_sigma

    frames, fps = sim_schedule(tracks.t)  # the checks change positions and ids, never the clock
    if options.units not in (None, "m"):  # converted units re-match tracks without ids: checks first
        tracks, reg = check_geometry(tracks, cloud, options.units)
        xs = _simulate_as_given(cloud, scene, frames, fps, tracks.ids, device, options, log)
    else:
        with ThreadPoolExecutor(1, thread_name_prefix="pixie-checks") as pool:
            geometry = pool.submit(check_geometry, tracks, cloud, options.units)
            try:
                xs = _simulate_as_given(cloud, scene, frames, fps, tracks.ids, device, options, log)
            except BaseException:
                geometry.result()  # an input error of the tracks comes first, as when the checks ran first
                raise
            checked, reg = geometry.result()
        if not np.array_equal(checked.ids, tracks.ids):  # registered and re-matched: other Gaussians
            xs = _simulate_as_given(cloud, scene, frames, fps, checked.ids, device, options, log)
        tracks = checked
    delta, loss_best, loss_zero = fit_time_offset(xs, fps, tracks.x, tracks.visible, tracks.t,
                                                  max_frames=OFFSET_SEARCH_FRAMES)
    reg.time_offset_s = float(delta)
    # a clock offset is a pure time shift: it must explain most of the early misfit, and a best
    # shift at the edge of the search (±3 frames) is a missing effect (e.g. an anchored part that
    # never moves looks like a late release), not a clock
    at_edge = abs(delta) * fps > OFFSET_SEARCH_FRAMES - 0.3
    if abs(delta) * fps >= 0.5 and loss_best < OFFSET_MAX_LOSS_RATIO * loss_zero and not at_edge:
        t_new = tracks.t - delta
        tracks = MeasuredTracks(t_new, tracks.x, tracks.visible, tracks.ids, tracks.match_distance, tracks.source)
        reg.time_offset_applied = True
        reg.warnings.append(f"start-time offset {delta:+.4f} s ({delta * fps:+.2f} frames) fitted on the early "
                            "frames and applied: simulation time = measured time − offset")
        stage(reg.warnings[-1])
    pred = sample_at(xs, fps, tracks.t)
    r = residuals(tracks.x, pred, tracks.visible)
    part = cloud.get("part_id")[tracks.ids]
    bad, z = outlier_tracks(r, tracks.visible, cloud.means[tracks.ids].astype(np.float64), part,
                            noise_sigma(r, tracks.visible))
    if bad.any() and (~bad).sum() >= 10:
        reg.outliers = [{"track": int(m), "gaussian": int(tracks.ids[m]), "z": round(float(z[m]), 1)}
                        for m in np.nonzero(bad)[0]]
        reg.warnings.append(f"{int(bad.sum())} outlier track(s) left out (their residual departs from their "
                            f"neighbours'): {[o['track'] for o in reg.outliers]}")
        stage(reg.warnings[-1])
        keep = np.nonzero(~bad)[0]
        tracks = tracks.subset_points(keep)
        pred = pred[:, keep]
    # the baseline the forward model would compute: same schedule, same sampling
    f_model, fps_model = sim_schedule(tracks.t)
    primed = sample_at(xs[:f_model], fps_model, tracks.t) if abs(fps_model - fps) < 1e-9 else None
    if primed is not None and bad.any() and (~bad).sum() >= 10:
        primed = primed[:, np.nonzero(~bad)[0]]
    return tracks, reg, primed


def _simulate_as_given(cloud: SplatCloud, scene, frames: int, fps: float, ids: np.ndarray, device: str,
                       options: DiagnoseOptions, log: list[SimRecord] | None) -> np.ndarray:
    """The tracked Gaussians `ids` of the model as given over frames + 4 frames → (F, M, 3) float64."""
    import time

    from ..progress import is_quiet, set_quiet
    from ..sim.run import simulate

    quiet = is_quiet()
    set_quiet(True)
    start = time.perf_counter()
    sim_stats: dict = {}
    try:
        stage("checks: simulating the model as given for the start-time offset and outlier tracks")
        if options.batch:  # the same solver path as every fitting run (sim/batch.py)
            from ..sim.batch import simulate_batch

            traj = simulate_batch([(cloud, scene)], frames + 4, fps, device=device, fill=options.fill,
                                  points=ids, stats=sim_stats)[0]
            if isinstance(traj, Exception):
                raise traj
            xs = traj.x.astype(np.float64)
        else:
            traj = simulate(cloud, scene, frames + 4, fps, device=device, fill=options.fill)
            xs = traj.x[:, ids].astype(np.float64)
    finally:
        set_quiet(quiet)
    if log is not None:
        log.append(SimRecord.since("checks", start, 1, len(cloud), int(scene.domain.grid), frames + 4, sim_stats))
    return xs


def _settle_on_full_model(runner: _Runner, problem: Problem, result: RoundResult, by_key: dict,
                          scene0, cloud0) -> tuple[Candidate, tuple]:
    """The round's winner polished on the full model — and so are its close rivals: significant
    candidates within RIVAL_WITHIN of its ΔBIC on the reduced model (e.g. linear damping and
    quadratic drag on a short toss), where the reduced model's own error can decide the order.
    The one with the smallest full-model SSE is added (and put first in the round's ranking)
    → (its candidate, _polish_on_full_model's result)."""
    chosen = result.chosen
    assert chosen is not None
    rivals = [s for s in result.ranking[1:] if s.significant and (s.effect, s.part) in by_key
              and s.delta_bic >= (1.0 - RIVAL_WITHIN) * chosen.delta_bic][:MAX_RIVALS]
    cands, polishes = [], []
    for s in [chosen] + rivals:
        cand = by_key[(s.effect, s.part)]
        scene1, cloud1 = cand.effect.apply(scene0, cloud0, cand.part, dict(s.params))
        cands.append(cand)
        polishes.append(_polish_on_full_model(runner, problem, cand, s, scene0, cloud0, scene1, cloud1))
    settled = list(zip(cands, _run_in_lockstep(runner.model, polishes)))
    best_cand, best = min(settled, key=lambda item: item[1][3].sse)
    if rivals:
        stage("full-model check of close rivals: " + ", ".join(
            f"{c.label} SSE {out[3].sse:.4g}" for c, out in settled) + f" → {best_cand.label}")
        runner.model.set_baseline(best[0], best[1], full_prediction=best[2])  # cached: no new run
        if best[3].effect != chosen.effect or best[3].part != chosen.part:
            old = next(i for i, s in enumerate(result.ranking) if (s.effect, s.part) == (best[3].effect, best[3].part))
            result.ranking.insert(0, result.ranking.pop(old))
    return best_cand, best


def _run_in_lockstep(model: ForwardModel, polishes: list) -> list:
    """Drive several _polish_on_full_model generators together: each step's full-model runs of
    all of them go out as ONE batched simulation (model.simulate_full_many) → their results."""
    results: list = [None] * len(polishes)
    requests = {i: next(g) for i, g in enumerate(polishes)}
    while requests:
        keys = list(requests)
        preds = model.simulate_full_many([requests[i] for i in keys])
        for i, pred in zip(keys, preds):
            try:
                requests[i] = polishes[i].throw(pred) if isinstance(pred, Exception) else polishes[i].send(pred)
            except StopIteration as done:
                results[i] = done.value
                del requests[i]
    return results


def _polish_on_full_model(runner: _Runner, problem: Problem, winner: Candidate, chosen: Scored,
                          scene0, cloud0, scene1, cloud1):
    """Full-model check (and up to MAX_CORRECTIONS secant corrections) of an effect fitted on
    the reduced model.

    The reduced model can get the SIZE of an effect's change a little wrong (coarser grid); the
    full runs at θ₀ (current model) and θ* (fitted) give the full model's change Δ along the
    fitted direction, and λ = Δ·r/Δ·Δ rescales the parameter step (in its near-linear
    coordinate) so the full model matches best; one more full run confirms it, and while λ
    still moves by more than 5 % and the fit improves, the step is rescaled again from the
    newest run (a response that is not linear in the parameter needs more than one). The
    chosen effect is re-scored with full-model residuals either way.

    A generator: it yields each (scene, cloud) whose full-model prediction it needs and is sent
    that prediction (_run_in_lockstep batches the runs of several); it returns
    (scene1, cloud1, pred1, rescored) and leaves (scene1, cloud1) as the model's baseline.
    """
    from .fit import from_linear_coord, linear_coord

    model = runner.model
    pred1 = yield scene1, cloud1
    sse1 = float(np.sum(residuals(problem.measured_x, pred1, problem.visible) ** 2))
    params = winner.params
    if params and all(p.off is not None for p in params):
        corrections = []
        for _ in range(MAX_CORRECTIONS):
            delta = problem.flat(pred1) - problem.flat(problem.base_pred)
            dd = float(delta @ delta)
            lam = float(delta @ problem.flat(problem.r0)) / dd if dd > 0 else 1.0
            if not (np.isfinite(lam) and abs(lam - 1.0) > 0.05):
                break
            lam = float(np.clip(lam, 0.25, 4.0))
            values = {}
            for p in params:
                u0, u1 = linear_coord(p, p.off), linear_coord(p, chosen.params[p.name])
                values[p.name] = float(np.clip(from_linear_coord(p, u0 + lam * (u1 - u0)), p.lo, p.hi))
            s2, c2 = winner.effect.apply(scene0, cloud0, winner.part, values)
            pred2 = yield s2, c2
            sse2 = float(np.sum(residuals(problem.measured_x, pred2, problem.visible) ** 2))
            if not sse2 < sse1:
                break
            corrections.append(lam)
            scene1, cloud1, pred1, sse1 = s2, c2, pred2, sse2
            chosen = Scored(**{**chosen.__dict__, "params": values})
        if corrections:
            stage(f"full-model correction of {winner.label}: step × {' × '.join(f'{c:.2f}' for c in corrections)}")
    n = runner.tracks.num_observations
    rescored = score_candidate(chosen.effect, chosen.part, dict(chosen.params), chosen.num_params, sse1,
                               problem.base_sse, n, runner.sigma, chosen.evaluations,
                               runner.options.bic_threshold, runner.options.min_excess_explained,
                               runner.original_sse, floor_sigma=runner.floor_c)
    rescored.evidence = evidence(problem, pred1, {"part": problem.cloud.get("part_id")[runner.tracks.ids]},
                                 runner.tracks.t)
    rescored.significant = chosen.significant
    model.set_baseline(scene1, cloud1, full_prediction=pred1)
    return scene1, cloud1, pred1, rescored
