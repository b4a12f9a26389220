"""Issue 12 robustness: the shipped checkpoint's per-Gaussian material classes under capture artefacts.

Each perturbation is applied alone to a clean generated object and the classes are compared with the
clean object's own prediction (agreement = share of the original Gaussians whose class is unchanged).
The expected answer is not produced by the code under test: it is "nothing changes", and the
perturbations are built here from their definitions (random unit directions scaled to an exact
‖f_rest‖, opacity logits drawn from a logit-normal fitted to real captures, uniform floaters, an exact
rotation). The perturbation helpers are shared with benchmarks/bench_robustness.py (every category,
opacities resampled from the real captures, the f_rest sweep, the prepared path).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from pixie_gs.splat import SplatCloud, quat_to_rotmat, rotmat_to_quat

# Opacity logits of real captures: a logit-normal with the captures' median α ≈ 0.28 and their spread
# (benchmarks/bench_splat_stats.py on ../shared/real; docs/real_vs_generated.md).
CAPTURE_LOGIT_MEAN = -0.94
CAPTURE_LOGIT_STD = 2.6
AGREEMENT_TARGET = 0.95


# ---------------------------------------------------------------------------------- perturbations
def with_f_rest(cloud: SplatCloud, energy: float, degree: int, rng: np.random.Generator) -> SplatCloud:
    """A copy whose every Gaussian has view-dependent colour of SH `degree` (1–3) with ‖f_rest‖ = `energy`
    exactly (a random direction per Gaussian); the DC colour is untouched."""
    k = 3 * ((degree + 1) ** 2 - 1)
    rest = rng.normal(size=(len(cloud), k))
    rest *= energy / np.maximum(np.linalg.norm(rest, axis=1, keepdims=True), 1e-12)
    out = cloud.copy()
    out.sh_rest = rest.astype(np.float32)
    order = [c for c in out.property_order if not c.startswith("f_rest_")]
    at = order.index("f_dc_2") + 1 if "f_dc_2" in order else len(order)
    out.property_order = order[:at] + [f"f_rest_{i}" for i in range(k)] + order[at:]
    return out


def with_opacity_logits(cloud: SplatCloud, logits: np.ndarray) -> SplatCloud:
    """A copy with the given per-Gaussian opacity logits (N,)."""
    out = cloud.copy()
    out.opacity_logits = np.asarray(logits, np.float32).reshape(len(cloud))
    return out


def with_floaters(cloud: SplatCloud, share: float, rng: np.random.Generator, grow: float = 0.0) -> SplatCloud:
    """The cloud followed by round(share·N) floaters: copies of random Gaussians (size, colour, opacity)
    moved to uniform positions in the object's box, grown by `grow` × its extent on every side. The
    original Gaussians keep their indices 0…N−1."""
    n = len(cloud)
    k = int(round(share * n))
    lo, hi = cloud.means.min(0).astype(np.float64), cloud.means.max(0).astype(np.float64)
    pad = grow * (hi - lo)
    extra = cloud.subset(rng.integers(0, n, k))
    extra.means = rng.uniform(lo - pad, hi + pad, (k, 3)).astype(np.float32)
    return SplatCloud.concatenate([cloud, extra])


def rotation_about_horizontal_axis(degrees: float, rng: np.random.Generator) -> np.ndarray:
    """(3,3) rotation by `degrees` about a random horizontal (xy-plane) axis: a tilt away from +z."""
    a, phi = math.radians(degrees), rng.uniform(0, 2 * math.pi)
    axis = np.array([math.cos(phi), math.sin(phi), 0.0])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def tilted(cloud: SplatCloud, degrees: float, rng: np.random.Generator) -> SplatCloud:
    """A copy tilted by `degrees` about a random horizontal axis through its centre (means and
    Gaussian orientations rotate together)."""
    R = rotation_about_horizontal_axis(degrees, rng)
    centre = cloud.means.astype(np.float64).mean(0)
    out = cloud.copy()
    out.means = ((cloud.means - centre) @ R.T + centre).astype(np.float32)
    out.rotations = rotmat_to_quat(R[None] @ quat_to_rotmat(cloud.quats)).astype(np.float32)
    return out


# ---------------------------------------------------------------------------------- prediction
def predict(cloud: SplatCloud, prepared: bool = False, device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """(material_id, confidence) per Gaussian from the shipped checkpoint on `device`: the plain path
    (`annotate_cloud`, +z up) or, with `prepared`, the default `pixie annotate` path (floaters, up,
    ground and objects found by `prepare_cloud` first)."""
    from pixie_gs.annotate import annotate_cloud

    if prepared:
        from pixie_gs.prepare import prepare_cloud

        prepared_cloud, scene = prepare_cloud(cloud, up="auto")
        out = annotate_cloud(prepared_cloud, None, device, prepared=scene)
    else:
        out = annotate_cloud(cloud, None, device, "z")
    return out.get("material_id").astype(np.int64), out.get("confidence").astype(np.float32)


def agreement(clean: np.ndarray, perturbed: np.ndarray) -> float:
    """Share of the clean object's Gaussians (the first len(clean) of `perturbed`) whose class is unchanged."""
    return float((np.asarray(perturbed)[:len(clean)] == np.asarray(clean)).mean())


# ---------------------------------------------------------------------------------- tests
def test_perturbations_do_what_they_say():
    """Known answers for the helpers themselves: exact ‖f_rest‖ and degree, floaters inside the grown
    box with the originals untouched, a tilt of exactly the angle that keeps shapes."""
    rng = np.random.default_rng(0)
    n = 500
    cloud = SplatCloud.from_arrays(rng.uniform(-1, 1, (n, 3)), log_scales=rng.normal(-4, 0.3, (n, 3)),
                                   rotations=rng.normal(size=(n, 4)), rgb=rng.uniform(0, 1, (n, 3)))
    sh = with_f_rest(cloud, 0.5, 3, rng)
    assert sh.sh_degree == 3 and sh.sh_rest.shape == (n, 45)
    np.testing.assert_allclose(np.linalg.norm(sh.sh_rest, axis=1), 0.5, rtol=1e-5)
    np.testing.assert_array_equal(sh.sh_dc, cloud.sh_dc)
    assert [c for c in sh.property_order if c.startswith("f_rest_")] == [f"f_rest_{i}" for i in range(45)]

    fl = with_floaters(cloud, 0.05, rng, grow=0.25)
    assert len(fl) == n + 25
    np.testing.assert_array_equal(fl.means[:n], cloud.means)
    lo, hi = cloud.means.min(0), cloud.means.max(0)
    assert np.all(fl.means[n:] >= lo - 0.25 * (hi - lo) - 1e-6) and np.all(fl.means[n:] <= hi + 0.25 * (hi - lo) + 1e-6)
    assert (fl.means[n:] < lo).any() or (fl.means[n:] > hi).any()  # some really lie outside the object's box

    t = tilted(cloud, 30.0, rng)
    c0 = cloud.means - cloud.means.mean(0)
    c1 = t.means - t.means.mean(0)
    np.testing.assert_allclose(np.linalg.norm(c1, axis=1), np.linalg.norm(c0, axis=1), rtol=1e-5, atol=1e-6)
    R, *_ = np.linalg.lstsq(c0.astype(np.float64), c1.astype(np.float64), rcond=None)
    assert math.degrees(math.acos(np.clip(R.T[2, 2], -1, 1))) == pytest.approx(30.0, abs=0.01)  # z moved by 30°
    np.testing.assert_allclose(np.linalg.eigvalsh(t.covariances()), np.linalg.eigvalsh(cloud.covariances()),
                               rtol=1e-4, atol=1e-9)


@pytest.mark.parametrize("name", ["books", "fruit"])
def test_new_categories_keep_their_classes_under_capture_artefacts(name):
    """Two of the sixteen everyday categories (held-out accuracy of the shipped checkpoint: books and fruit
    1.00; docs/model_card.md): degree-3
    ‖f_rest‖ = 0.5, capture-like opacities, 5 % floaters and a 30° tilt each keep ≥ 95 % of the clean
    prediction's classes. (The paper-class objects: tests/test_model_real_confidence.py; every category:
    benchmarks/bench_robustness.py.)"""
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table

    table = load_class_table()
    index = list(table).index(name)
    clean, _ = build_object(table[name], object_seed(77, "test", index), 6000)
    rng = np.random.default_rng(index)
    base, base_conf = predict(clean)
    assert base_conf.min() >= 0.0 and base_conf.max() <= 1.0
    cases = {
        "f_rest 0.5 (degree 3)": with_f_rest(clean, 0.5, 3, rng),
        "capture opacity": with_opacity_logits(clean, rng.normal(CAPTURE_LOGIT_MEAN, CAPTURE_LOGIT_STD, len(clean))),
        "5 % floaters": with_floaters(clean, 0.05, rng),
        "30° tilt": tilted(clean, 30.0, rng),
    }
    scores = {what: agreement(base, predict(cloud)[0]) for what, cloud in cases.items()}
    assert min(scores.values()) >= AGREEMENT_TARGET, (name, scores)


def test_untrained_channels_are_held_as_in_training():
    """A channel that was zero on every training object (mean and std 0 in the checkpoint's statistics) is
    held at zero at inference and left out of the in-distribution score; channels that varied are not."""
    from pixie_gs.model.predict import in_distribution_score, untrained_channels

    stats = {"channels": ["occupancy", "opacity", "sh_energy"], "mean": [1.0, 0.8, 0.0], "std": [0.0, 0.1, 0.0]}
    meta = {"feature_stats": stats}
    assert untrained_channels(meta) == ["sh_energy"]
    assert untrained_channels({}) == []
    assert in_distribution_score(meta, np.array([1.0, 0.8, 0.4])) == 1.0  # f_rest alone is not "unlike training"
    assert in_distribution_score(meta, np.array([1.0, 3.0, 0.0])) < 0.1  # opacity far outside still is


def test_view_dependent_colour_leaves_the_shipped_checkpoints_classes_and_confidence():
    """A glass bottle with degree-3 ‖f_rest‖ = 0.5 — the case that flipped 99 % of an older checkpoint's
    classes and zeroed its confidence (docs/model_card.md) — keeps ≥ 95 % of the clean prediction's
    classes, and its confidence does not collapse (at least half the clean object's). The shipped
    checkpoint trained on objects with and without view-dependent colour (its sh_energy channel varied)."""
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.model.checkpoint import load_checkpoint
    from pixie_gs.model.predict import untrained_channels

    assert "sh_energy" not in untrained_channels(load_checkpoint(None, "cpu").meta)
    table = load_class_table()
    index = list(table).index("glass_bottles")
    clean, _ = build_object(table["glass_bottles"], object_seed(77, "test", index), 4000)
    base, base_conf = predict(clean)
    classes, conf = predict(with_f_rest(clean, 0.5, 3, np.random.default_rng(1)))
    assert agreement(base, classes) >= AGREEMENT_TARGET
    assert base_conf.mean() > 0.05 and conf.mean() >= 0.5 * base_conf.mean()