"""Per-Gaussian statistics of real captures vs generated training objects (issue 12).

For each splat: opacity α, log std-dev relative to the object's size (log10 of mean σ / robust
extent, and of the largest σ: large Gaussians fill a grid as a solid would), anisotropy
log10(σ_max/σ_min), ‖f_rest‖ per SH degree, colour noise (|RGB − mean RGB of the 8 nearest neighbours|),
saturation and value of the colour (HSV: (max − min)/max and max of RGB; baked light and shade, dataset/lighting.py),
nearest-neighbour spacing relative to the extent, and the floater share (Gaussians whose 8th-neighbour
distance is over 5× the median). Real captures pooled vs generated objects pooled: quantiles
(5/25/50/75/95 %) and the two-sample Kolmogorov–Smirnov distance D.

usage: python benchmarks/bench_splat_stats.py [--real DIR] [--extra-real FILE ...] [--generated DIR] [--count N]
                                             [--out docs/real_vs_generated.md]
--generated: a `pixie generate` split folder (…/train); without it, N objects are generated now
(seed 0, split test, 30k Gaussians each) with the current generator.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import ks_2samp

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from pixie_gs.formats import read_any  # noqa: E402

REAL = ["redplant.ply", "pool.ply", "guitar.compressed.ply", "donut_fused.ply"]
STATS = ["opacity", "log10_rel_scale", "log10_rel_max_scale", "log10_anisotropy", "f_rest_deg1", "f_rest_deg2", "f_rest_deg3",
         "colour_noise", "saturation", "value", "log10_rel_spacing", "floater"]
PER_SPLAT = 40_000  # Gaussians sampled per splat (each splat weighs the same)


def splat_stats(path: Path, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Per-Gaussian statistics of one splat (a random subset of PER_SPLAT Gaussians)."""
    c = read_any(path)
    idx = rng.choice(len(c), min(len(c), PER_SPLAT), replace=False)
    c = c.subset(np.sort(idx))
    lo, hi = np.percentile(c.means, 2, axis=0), np.percentile(c.means, 98, axis=0)
    extent = float(np.linalg.norm(hi - lo))
    s = c.scales.astype(np.float64)
    out = {"opacity": c.opacities.astype(np.float64),
           "log10_rel_scale": np.log10(s.mean(1) / extent),
           "log10_rel_max_scale": np.log10(s.max(1) / extent),  # the tail: large Gaussians filling a grid
           "log10_anisotropy": np.log10(s.max(1) / np.maximum(s.min(1), 1e-12))}
    rest = c.sh_rest.astype(np.float64)
    k = rest.shape[1] // 3
    per = rest.reshape(len(c), 3, k) if k else np.zeros((len(c), 3, 0))
    for deg, (a, b) in enumerate([(0, 3), (3, 8), (8, 15)], start=1):
        out[f"f_rest_deg{deg}"] = (np.linalg.norm(per[:, :, a:b].reshape(len(c), -1), axis=1) if k >= b
                                   else np.zeros(len(c)))
    tree = cKDTree(c.means)
    d, nb = tree.query(c.means, k=9)
    rgb = c.rgb().astype(np.float64)
    out["colour_noise"] = np.abs(rgb - rgb[nb[:, 1:]].mean(1)).mean(1)
    value = np.clip(rgb, 0.0, 1.0).max(1)
    out["saturation"] = (value - np.clip(rgb, 0.0, 1.0).min(1)) / np.maximum(value, 1e-6)
    out["value"] = value
    out["log10_rel_spacing"] = np.log10(np.maximum(d[:, 1], 1e-9) / extent)
    out["floater"] = (d[:, 8] > 5 * np.median(d[:, 8])).astype(float)
    return out


def pooled(paths: list[Path], rng: np.random.Generator) -> dict[str, np.ndarray]:
    per = [splat_stats(p, rng) for p in paths]
    return {k: np.concatenate([x[k] for x in per]) for k in STATS}


def table(real: dict, gen: dict, title: str) -> str:
    q = [5, 25, 50, 75, 95]
    lines = [f"### {title}", "", "| statistic | real " + " / ".join(f"p{v}" for v in q) + " | generated "
             + " / ".join(f"p{v}" for v in q) + " | KS D |", "|---|---|---|---|"]
    for k in STATS:
        if k == "floater":
            lines.append(f"| floater share | {real[k].mean():.3f} | {gen[k].mean():.3f} | "
                         f"{abs(real[k].mean() - gen[k].mean()):.3f} (difference) |")
            continue
        r, g = np.percentile(real[k], q), np.percentile(gen[k], q)
        d = ks_2samp(real[k], gen[k]).statistic
        lines.append(f"| {k} | " + " / ".join(f"{v:.3g}" for v in r) + " | " + " / ".join(f"{v:.3g}" for v in g)
                     + f" | {d:.3f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", default=str(ROOT.parent / "shared" / "real" / "orig"))
    ap.add_argument("--extra-real", nargs="*", default=[], metavar="FILE",
                    help="more real captures to pool with the four (e.g. the second set's plant.splat)")
    ap.add_argument("--generated", default=None)
    ap.add_argument("--count", type=int, default=20)
    ap.add_argument("--title", default="generated objects")
    ap.add_argument("--out", default=None, help="append the table to this markdown file")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    real_paths = [Path(args.real) / n for n in REAL] + [Path(f) for f in args.extra_real]
    real = pooled(real_paths, rng)
    if args.generated:
        gdir = Path(args.generated)
    else:
        from pixie_gs.dataset.generate import generate_split

        gdir = generate_split(tempfile.mkdtemp(), args.count, seed=0, split="test", workers=2, n_gaussians=30_000)
    gpaths = sorted(gdir.glob("*.ply"))[: args.count]
    gen = pooled(gpaths, rng)
    text = table(real, gen, f"{args.title}: {len(gpaths)} objects from {gdir} vs {len(real_paths)} real captures")
    print(text)
    if args.out:
        with open(args.out, "a") as f:
            f.write("\n" + text)


if __name__ == "__main__":
    main()
