"""Reliability diagram of the per-Gaussian `confidence` (issue 12): is it a probability of being right?

Held-out generated objects (test-split seeds the shipped model never saw) are annotated on CPU with a
checkpoint (the shipped one by default); each Gaussian's `confidence` (the class probability of its
nearest material voxel × the object's in-distribution factor, exactly what `pixie annotate` writes) is
binned and compared with the share of Gaussians in the bin whose class equals the generator's label.
Two held-out sets: the ten categories the shipped model was trained on (clean objects), and all 26
categories made capture-like (the generator's default). Expected calibration error (ECE) =
Σ_bins (n_b / N)·|accuracy_b − mean confidence_b|, with 10 equal-width bins.

Recalibration, both fitted on a *validation* split (val seeds) and scored on the test objects:
temperature scaling (one T > 0 dividing the material logits, minimising the negative log-likelihood of
the true class), and a two-input logistic map P(right) = σ(a·logit p + b·ln(in-distribution) + c) (Platt
scaling that can also re-weigh the out-of-distribution factor, which temperature cannot touch). The
figure shows the confidence as shipped and each map that lowers the test ECE.

    python scripts/calibration_diagram.py docs/calibration.png                  # ~10 min on 2 busy cores
    python scripts/calibration_diagram.py /tmp/c.png --per-class 1 --val-per-class 1 --gaussians 6000
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BINS = 10


@dataclass
class Outputs:
    """Per-Gaussian material logits (M,7), true class (M,), and the object's in-distribution factor."""

    logits: np.ndarray
    true: np.ndarray
    in_distribution: float
    category: str


def object_outputs(loaded, cloud, category: str, device: str = "cpu") -> Outputs:
    """The shipped inference path (`predict_materials` + nearest-voxel transfer), keeping the logits."""
    import torch

    from pixie_gs.field import feature_grid
    from pixie_gs.materials import BACKGROUND
    from pixie_gs.model.predict import (_forward, classes_from_logits, in_distribution_score,
                                        object_feature_summary)
    from pixie_gs.transfer import nearest_voxel_index

    spec = loaded.features
    grid = feature_grid(cloud, spec.resolution, list(spec.extra_names), device=device,
                        filter_voxels=spec.filter_voxels, margin=spec.margin)
    values = torch.as_tensor(grid.values, device=device)[None]
    occupied = torch.as_tensor(grid.occupancy, device=device)[None]
    logits, _ = _forward(loaded, values, grid.channels)
    classes = classes_from_logits(logits, occupied)[0].cpu().numpy()
    ind = in_distribution_score(loaded.meta, object_feature_summary(values, occupied)[0].cpu().numpy())
    logits = logits.cpu()
    vox = nearest_voxel_index(grid.extra["means_unit"], classes, grid.occupancy)
    lg = logits[0, :BACKGROUND].permute(1, 2, 3, 0).numpy()[vox[:, 0], vox[:, 1], vox[:, 2]]
    return Outputs(lg.astype(np.float64), cloud.get("material_id").astype(np.int64), float(ind), category)


def confidence_and_correct(outs: list[Outputs], temperature: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(confidence, correct) per Gaussian over every object, with the logits divided by `temperature`."""
    conf, ok = [], []
    for o in outs:
        z = o.logits / temperature
        z = z - z.max(1, keepdims=True)
        p = np.exp(z)
        p /= p.sum(1, keepdims=True)
        conf.append(p.max(1) * o.in_distribution)
        ok.append(p.argmax(1) == o.true)
    return np.concatenate(conf), np.concatenate(ok)


def reliability(conf: np.ndarray, ok: np.ndarray, bins: int = BINS) -> dict:
    """Per equal-width bin: count, mean confidence, accuracy; and the ECE and MCE over bins."""
    edges = np.linspace(0.0, 1.0, bins + 1)
    b = np.clip(np.digitize(conf, edges[1:-1]), 0, bins - 1)
    count = np.bincount(b, minlength=bins)
    mean_conf = np.bincount(b, conf, bins) / np.maximum(count, 1)
    acc = np.bincount(b, ok.astype(np.float64), bins) / np.maximum(count, 1)
    gap = np.abs(acc - mean_conf)
    return {"edges": edges.tolist(), "count": count.tolist(), "confidence": mean_conf.tolist(),
            "accuracy": acc.tolist(), "ece": float((count * gap).sum() / max(count.sum(), 1)),
            "mce": float(gap[count > 0].max()) if (count > 0).any() else 0.0,
            "overall_accuracy": float(ok.mean()), "mean_confidence": float(conf.mean())}


def fit_temperature(outs: list[Outputs]) -> float:
    """T minimising the mean negative log-likelihood of the true class (golden-section on log T)."""
    logits = np.concatenate([o.logits for o in outs])
    true = np.concatenate([o.true for o in outs])
    ok = (true >= 0) & (true < logits.shape[1])
    logits, true = logits[ok], true[ok]

    def nll(log_t: float) -> float:
        z = logits / np.exp(log_t)
        z = z - z.max(1, keepdims=True)
        return float(np.mean(np.log(np.exp(z).sum(1)) - z[np.arange(len(z)), true]))

    lo, hi = np.log(0.05), np.log(20.0)
    g = (np.sqrt(5) - 1) / 2
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    for _ in range(60):
        if nll(a) < nll(b):
            hi, b = b, a
            a = hi - g * (hi - lo)
        else:
            lo, a = a, b
            b = lo + g * (hi - lo)
    return float(np.exp((lo + hi) / 2))


def _logistic_inputs(outs: list[Outputs]) -> tuple[np.ndarray, np.ndarray]:
    """(X (M,3): logit of the class probability, ln in-distribution, 1; correct (M,)) per Gaussian."""
    xs, ys = [], []
    for o in outs:
        z = o.logits - o.logits.max(1, keepdims=True)
        p = np.exp(z)
        p /= p.sum(1, keepdims=True)
        pm = np.clip(p.max(1), 1e-6, 1 - 1e-6)
        xs.append(np.stack([np.log(pm / (1 - pm)), np.full(len(pm), np.log(max(o.in_distribution, 1e-6))),
                            np.ones(len(pm))], 1))
        ys.append(p.argmax(1) == o.true)
    return np.concatenate(xs), np.concatenate(ys).astype(np.float64)


def fit_logistic(outs: list[Outputs], ridge: float = 1e-3, steps: int = 100) -> np.ndarray:
    """Weights (a, b, c) of σ(a·logit p + b·ln ind + c): Newton's method with backtracking on the mean
    negative log-likelihood plus a small ridge on a and b (the steps never increase the objective)."""
    X, y = _logistic_inputs(outs)
    pen = np.array([ridge, ridge, 0.0])

    def objective(w: np.ndarray) -> float:
        t = X @ w
        return float(np.mean(np.logaddexp(0.0, t) - y * t) + 0.5 * (pen * w * w).sum())

    w = np.array([1.0, 0.0, 0.0])
    f = objective(w)
    for _ in range(steps):
        q = 1 / (1 + np.exp(-np.clip(X @ w, -30, 30)))
        grad = X.T @ (q - y) / len(y) + pen * w
        H = (X * (q * (1 - q))[:, None]).T @ X / len(y) + np.diag(pen) + 1e-9 * np.eye(3)
        step = np.linalg.solve(H, grad)
        t = 1.0
        while t > 1e-6 and objective(w - t * step) > f:
            t *= 0.5
        w_new = w - t * step
        f_new = objective(w_new)
        if f - f_new < 1e-12:
            break
        w, f = w_new, f_new
    return w


def logistic_confidence(outs: list[Outputs], w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(recalibrated confidence, correct) per Gaussian."""
    X, y = _logistic_inputs(outs)
    return 1 / (1 + np.exp(-np.clip(X @ w, -30, 30))), y.astype(bool)


def collect(loaded, names: list[str], per_class: int, seed: int, split: str, n: int, realistic: bool,
            desc: str, device: str = "cpu") -> list[Outputs]:
    """Outputs of `per_class` generated objects per category of `split` (object i: seed (seed, split, i))."""
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.progress import progress

    table = load_class_table()
    jobs = [(k * len(names) + i, name) for k in range(per_class) for i, name in enumerate(names)]
    outs = []
    for index, name in progress(jobs, desc, total=len(jobs), unit="obj"):
        cloud, _ = build_object(table[name], object_seed(seed, split, index), n, realistic=realistic)
        outs.append(object_outputs(loaded, cloud, name, device))
    return outs


def save_cache(path: str, sets: dict[str, tuple[list[Outputs], list[Outputs]]]) -> None:
    """Every object's Outputs of every held-out set, as one .npz."""
    arrays: dict[str, np.ndarray] = {}
    for si, (label, (test, val)) in enumerate(sets.items()):
        arrays[f"label_{si}"] = np.array(label)
        for part, outs in (("test", test), ("val", val)):
            for oi, o in enumerate(outs):
                key = f"{si}_{part}_{oi}"
                arrays[f"logits_{key}"], arrays[f"true_{key}"] = o.logits.astype(np.float32), o.true
                arrays[f"meta_{key}"] = np.array([o.in_distribution])
                arrays[f"category_{key}"] = np.array(o.category)
    np.savez_compressed(path, **arrays)


def load_cache(path: str) -> dict[str, tuple[list[Outputs], list[Outputs]]]:
    data = np.load(path)
    sets = {}
    si = 0
    while f"label_{si}" in data:
        parts = []
        for part in ("test", "val"):
            outs, oi = [], 0
            while f"logits_{si}_{part}_{oi}" in data:
                key = f"{si}_{part}_{oi}"
                outs.append(Outputs(data[f"logits_{key}"].astype(np.float64), data[f"true_{key}"],
                                    float(data[f"meta_{key}"][0]), str(data[f"category_{key}"])))
                oi += 1
            parts.append(outs)
        sets[str(data[f"label_{si}"])] = (parts[0], parts[1])
        si += 1
    return sets


def curves_of(result: dict) -> list[tuple[str, dict, str]]:
    """The curves to draw: per held-out set T = 1 (as shipped), plus the fitted T where it lowers the ECE."""
    colours = iter(["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"])
    curves = []
    for label, s in result["sets"].items():
        curves.append((f"{label}, T = 1", s["T1"], next(colours)))
        if s["fitted"]["ece"] < s["T1"]["ece"]:
            curves.append((f"{label}, T = {s['temperature']:.2f} (val)", s["fitted"], next(colours)))
        if "logistic" in s and s["logistic"]["ece"] < s["T1"]["ece"]:
            curves.append((f"{label}, logistic map (val)", s["logistic"], next(colours)))
    return curves


def draw(path: Path, curves: list[tuple[str, dict, str]]) -> None:
    """Reliability diagram (accuracy vs confidence per bin, bar widths = bins) over a histogram."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, hx) = plt.subplots(2, 1, figsize=(6.4, 7.2), gridspec_kw={"height_ratios": [3, 1]}, sharex=True)
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--", label="perfect calibration")
    width = 1.0 / BINS
    for k, (label, rel, colour) in enumerate(curves):
        count = np.asarray(rel["count"])
        has = count > 0
        conf, acc = np.asarray(rel["confidence"])[has], np.asarray(rel["accuracy"])[has]
        ax.plot(conf, acc, "o-", color=colour, lw=1.8, ms=5,
                label=f"{label}: ECE {rel['ece']:.3f}, acc. {rel['overall_accuracy']:.3f}")
        centres = np.asarray(rel["edges"][:-1]) + width / 2
        share = count / max(count.sum(), 1)
        off = (k - (len(curves) - 1) / 2) * width / (len(curves) + 0.5)
        hx.bar(centres + off, share, width / (len(curves) + 0.5), color=colour, alpha=0.85)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("accuracy of the Gaussians in the bin")
    ax.set_title("per-Gaussian material confidence vs accuracy\n(held-out generated objects, shipped checkpoint)")
    ax.legend(loc="lower right", fontsize=7.5)
    ax.grid(alpha=0.3)
    hx.set_xlabel("confidence (10 bins)")
    hx.set_ylabel("share of Gaussians")
    hx.set_yscale("log")
    hx.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="PNG to write (e.g. docs/calibration.png)")
    ap.add_argument("--checkpoint", default=None, help="checkpoint (default: the shipped one)")
    ap.add_argument("--per-class", type=int, default=3, help="test objects per category")
    ap.add_argument("--val-per-class", type=int, default=2, help="validation objects per category (temperature)")
    ap.add_argument("--gaussians", type=int, default=12000, help="Gaussians per object (±20 %%)")
    ap.add_argument("--seed", type=int, default=600, help="dataset seed of the held-out objects")
    ap.add_argument("--device", default="cpu", help="torch device for the model (cpu, cuda)")
    ap.add_argument("--json", default=None, help="also write every figure as JSON")
    ap.add_argument("--cache", default=None, metavar="NPZ",
                    help="keep the per-Gaussian logits here and reuse them on the next run (refits only)")
    ap.add_argument("--from-json", default=None, metavar="FILE",
                    help="only redraw the PNG from a JSON this script wrote (e.g. on a GPU box without matplotlib)")
    args = ap.parse_args()
    if args.from_json:
        draw(Path(args.out), curves_of(json.loads(Path(args.from_json).read_text())))
        print(f"wrote {args.out}")
        return

    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.model.checkpoint import load_checkpoint
    from pixie_gs.model.stats import PAPER_CLASSES

    t0 = time.perf_counter()
    loaded = load_checkpoint(args.checkpoint, args.device)
    every = list(load_class_table())
    sets = {"10 training categories, clean": (PAPER_CLASSES, False),
            "26 categories, capture-like": (every, True)}
    result: dict = {"checkpoint": loaded.path, "gaussians": args.gaussians, "seed": args.seed, "sets": {}}
    cached = load_cache(args.cache) if args.cache and Path(args.cache).is_file() else {}
    for label, (names, realistic) in sets.items():
        if label in cached:
            test, val = cached[label]
        else:
            test = collect(loaded, names, args.per_class, args.seed, "test", args.gaussians, realistic,
                           f"test: {label}", args.device)
            val = collect(loaded, names, args.val_per_class, args.seed, "val", args.gaussians, realistic,
                          f"val: {label}", args.device)
            cached[label] = (test, val)
            if args.cache:
                save_cache(args.cache, cached)
        T = fit_temperature(val)
        w = fit_logistic(val)
        rel1 = reliability(*confidence_and_correct(test))
        relT = reliability(*confidence_and_correct(test, T))
        relL = reliability(*logistic_confidence(test, w))
        result["sets"][label] = {"objects_test": len(test), "objects_val": len(val), "temperature": T,
                                 "T1": rel1, "fitted": relT, "logistic_weights": w.tolist(), "logistic": relL}
        print(f"{label}: {len(test)} test objects ({sum(len(o.true) for o in test)} Gaussians), "
              f"{len(val)} validation objects")
        print(f"  as shipped (T = 1): accuracy {rel1['overall_accuracy']:.4f}, mean confidence "
              f"{rel1['mean_confidence']:.4f}, ECE {rel1['ece']:.4f}, MCE {rel1['mce']:.4f}")
        print(f"  temperature fitted on validation: T = {T:.3f}: mean confidence {relT['mean_confidence']:.4f}, "
              f"ECE {relT['ece']:.4f}, MCE {relT['mce']:.4f}")
        print(f"  logistic map fitted on validation: a {w[0]:.3f}, b {w[1]:.3f}, c {w[2]:.3f}: mean confidence "
              f"{relL['mean_confidence']:.4f}, ECE {relL['ece']:.4f}, MCE {relL['mce']:.4f}")
        print("  bin          count   conf.    acc.")
        for i in range(BINS):
            if rel1["count"][i]:
                print(f"  {rel1['edges'][i]:.1f}–{rel1['edges'][i + 1]:.1f} {rel1['count'][i]:>10} "
                      f"{rel1['confidence'][i]:>7.3f} {rel1['accuracy'][i]:>7.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    try:
        draw(Path(args.out), curves_of(result))
    except ImportError as exc:  # matplotlib missing: the JSON can be drawn elsewhere with --from-json
        print(f"no picture ({exc}); redraw with --from-json")
        return
    print(f"wrote {args.out} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
