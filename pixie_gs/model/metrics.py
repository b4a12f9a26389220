"""The paper's evaluation columns: material accuracy and MSE of normalised log10 E, ν, log10 ρ.

Accumulated per occupied voxel and per Gaussian, with a per-class accuracy table (by true class)
and a per-object-category summary.
"""
from __future__ import annotations

import numpy as np

from ..materials import MATERIAL_NAMES, NUM_CLASSES

PHYSICAL_NAMES = ("log_E", "nu", "log_rho")


def separation_auroc(higher, lower) -> float:
    """Probability that a value drawn from `higher` exceeds one drawn from `lower` (ties count ½): the area
    under the ROC curve of telling the two groups apart by the value (0.5: not at all). A NaN compares as
    neither greater nor equal, so it counts as a loss."""
    return float(np.mean([(a > b) + 0.5 * (a == b) for a in higher for b in lower]))


class _Sums:
    def __init__(self) -> None:
        self.count = 0
        self.correct = 0
        self.sq = np.zeros(3)
        self.class_count = np.zeros(NUM_CLASSES, np.int64)
        self.class_correct = np.zeros(NUM_CLASSES, np.int64)

    def add(self, pred: np.ndarray, phys: np.ndarray, true: np.ndarray, true_phys: np.ndarray) -> None:
        self.count += len(true)
        ok = pred == true
        self.correct += int(ok.sum())
        self.sq += ((phys - true_phys) ** 2).sum(axis=0)
        self.class_count += np.bincount(true, minlength=NUM_CLASSES)[:NUM_CLASSES]
        self.class_correct += np.bincount(true[ok], minlength=NUM_CLASSES)[:NUM_CLASSES]

    def summary(self) -> dict:
        c = max(self.count, 1)
        mse = self.sq / c
        out = {"count": int(self.count), "accuracy": self.correct / c}
        out.update({f"mse_{k}": float(v) for k, v in zip(PHYSICAL_NAMES, mse)})
        out["mse_avg"] = float(mse.mean())
        out["per_class_accuracy"] = {MATERIAL_NAMES[k]: {"count": int(self.class_count[k]),
                                                         "accuracy": float(self.class_correct[k] / self.class_count[k])}
                                     for k in range(NUM_CLASSES) if self.class_count[k]}
        return out


class MetricAccumulator:
    """Sums over many objects; `summary()` gives the table as plain JSON-ready numbers."""

    def __init__(self) -> None:
        self.voxel = _Sums()
        self.gaussian = _Sums()
        self.by_object_class: dict[str, _Sums] = {}
        self.objects = 0

    def add_voxels(self, pred_class, pred_phys, true_class, true_phys, occupied) -> None:
        """Torch tensors (B,N,N,N), (B,3,N,N,N), …; only occupied voxels count."""
        occ = occupied.reshape(-1)
        pc = pred_class.reshape(-1)[occ].cpu().numpy()
        tc = true_class.reshape(-1)[occ].cpu().numpy()
        pp = pred_phys.permute(0, 2, 3, 4, 1).reshape(-1, 3)[occ].float().cpu().numpy()
        tp = true_phys.permute(0, 2, 3, 4, 1).reshape(-1, 3)[occ].float().cpu().numpy()
        self.voxel.add(pc, pp, tc, tp)

    def add_gaussians(self, pred_class: np.ndarray, pred_phys: np.ndarray, true_class: np.ndarray,
                      true_phys: np.ndarray, object_class: str = "") -> None:
        true_class = np.asarray(true_class, np.int64)
        pred_class = np.asarray(pred_class, np.int64)
        self.gaussian.add(pred_class, pred_phys, true_class, true_phys)
        self.by_object_class.setdefault(object_class or "?", _Sums()).add(pred_class, pred_phys, true_class, true_phys)
        self.objects += 1

    def summary(self) -> dict:
        out = {"objects": self.objects, "voxel": self.voxel.summary()}
        if self.gaussian.count:
            out["gaussian"] = self.gaussian.summary()
            out["by_object_class"] = {k: {key: v for key, v in s.summary().items() if key != "per_class_accuracy"}
                                      for k, s in sorted(self.by_object_class.items())}
        return out


def format_table(summary: dict) -> str:
    """The paper-style table as text: rows voxel/Gaussian, then the per-class accuracy tables."""
    lines = [f"objects: {summary['objects']}",
             f"{'unit':<10}{'count':>12}{'mat.acc':>10}{'logE mse':>10}{'nu mse':>10}{'logρ mse':>10}{'avg mse':>10}"]
    for unit in ("voxel", "gaussian"):
        if unit in summary:
            s = summary[unit]
            lines.append(f"{unit:<10}{s['count']:>12}{s['accuracy']:>10.4f}{s['mse_log_E']:>10.4f}"
                         f"{s['mse_nu']:>10.4f}{s['mse_log_rho']:>10.4f}{s['mse_avg']:>10.4f}")
    floor = summary.get("label_floor")
    if floor:
        lines.append(f"{'floor':<10}{'':>12}{'':>10}{floor['floor_log_E']:>10.4f}{floor['floor_nu']:>10.4f}"
                     f"{floor['floor_log_rho']:>10.4f}{floor['floor_avg']:>10.4f}")
        lines.append("  (floor: the labels' own spread, drawn at random within each part's range: the expected MSE of the best possible prediction)")
    for unit in ("voxel", "gaussian"):
        if unit in summary:
            lines.append(f"per-class accuracy ({unit}, by true material):")
            for name, s in summary[unit]["per_class_accuracy"].items():
                lines.append(f"  {name:<14}{s['count']:>12}{s['accuracy']:>10.4f}")
    if "by_object_class" in summary:
        lines.append("per object category (per Gaussian):")
        floors = (floor or {}).get("by_object_class", {})
        lines.append(f"  {'category':<14}{'gaussians':>12}{'mat.acc':>10}{'avg mse':>10}" + (f"{'floor':>10}" if floors else ""))
        for name, s in summary["by_object_class"].items():
            tail = f"{floors[name]:>10.4f}" if name in floors else ""
            lines.append(f"  {name:<14}{s['count']:>12}{s['accuracy']:>10.4f}{s['mse_avg']:>10.4f}{tail}")
    return "\n".join(lines)
